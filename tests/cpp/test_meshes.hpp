// Small procedural meshes for the C++ tests.
#pragma once

#include <algorithm>
#include <cmath>

#include "matdeform/types.hpp"

namespace matdeform::meshes {

// Closed box-section bar along x: (nx+1) rings of 4 vertices, length `length`, unit cross
// section, capped at both ends. Returns 4(nx+1) vertices, 8 nx + 4 triangles.
inline void make_bar(int nx, double length, Vertices* V, Faces* F) {
  V->resize(4 * (nx + 1), 3);
  const double ring[4][2] = {{-0.5, -0.5}, {0.5, -0.5}, {0.5, 0.5}, {-0.5, 0.5}};
  for (int i = 0; i <= nx; ++i) {
    for (int j = 0; j < 4; ++j) {
      V->row(4 * i + j) << length * i / nx, ring[j][0], ring[j][1];
    }
  }
  F->resize(8 * nx + 4, 3);
  int f = 0;
  for (int i = 0; i < nx; ++i) {
    for (int j = 0; j < 4; ++j) {
      const int a = 4 * i + j, b = 4 * i + (j + 1) % 4, c = a + 4, d = b + 4;
      F->row(f++) << a, b, d;
      F->row(f++) << a, d, c;
    }
  }
  F->row(f++) << 0, 2, 1;
  F->row(f++) << 0, 3, 2;
  const int o = 4 * nx;
  F->row(f++) << o, o + 1, o + 2;
  F->row(f++) << o, o + 2, o + 3;
}

// Flat (nx x ny) grid of squares split into triangles in the z=0 plane.
inline void make_grid(int nx, int ny, Vertices* V, Faces* F) {
  V->resize((nx + 1) * (ny + 1), 3);
  for (int j = 0; j <= ny; ++j)
    for (int i = 0; i <= nx; ++i) V->row(j * (nx + 1) + i) << i, j, 0.0;
  F->resize(2 * nx * ny, 3);
  int f = 0;
  for (int j = 0; j < ny; ++j)
    for (int i = 0; i < nx; ++i) {
      const int a = j * (nx + 1) + i, b = a + 1, c = a + nx + 1, d = c + 1;
      F->row(f++) << a, b, d;
      F->row(f++) << a, d, c;
    }
}

// Open fan of `count` triangles around a centre vertex 0 (rim vertices 1..count+1 on an arc of
// min(1.5, 5.2 / count) rad per triangle), with the centre raised so the fan is not planar.
inline void make_fan(int count, Vertices* V, Faces* F) {
  V->resize(count + 2, 3);
  V->row(0) << 0.0, 0.0, 0.3;
  const double step = std::min(1.5, 5.2 / count);
  for (int i = 0; i <= count; ++i) V->row(i + 1) << std::cos(step * i), std::sin(step * i), 0.0;
  F->resize(count, 3);
  for (int i = 0; i < count; ++i) F->row(i) << 0, i + 1, i + 2;
}

}  // namespace matdeform::meshes
