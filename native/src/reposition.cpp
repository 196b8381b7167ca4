#include "matdeform/reposition.hpp"

#include <Eigen/Dense>
#include <Eigen/SparseCore>
#include <algorithm>
#include <cmath>
#include <limits>
#include <mutex>
#include <numeric>
#include <stdexcept>
#include <string>

#include "matdeform/frames.hpp"
#include "matdeform/mesh.hpp"
#include "matdeform/stiffness.hpp"
#include "simd.hpp"
#include "sparse_cholesky.hpp"
#include "task_pool.hpp"

namespace matdeform {

namespace {
using Col3 = Eigen::Matrix<double, Eigen::Dynamic, 3>;  // column-major (rows,3)

// Position of entry e (column-major) of face i's matrix in the grouped layout.
inline size_t group_index(int i, int e) {
  return static_cast<size_t>(kGroupStride) * (i / kGroupFaces) + kGroupFaces * e + i % kGroupFaces;
}

// For the groups [gb, ge) (grouped layout, types.hpp): local holds T on entry and T * H^T on
// return, whose column l is the right-hand-side term of the face's local vertex l. H is zero for
// unusable faces and padding lanes.
MD_ALWAYS_INLINE void condense_body(const double* H, double* local, int gb, int ge) {
  for (int g = gb; g < ge; ++g) {
    // A group is nine Vec4d: entry e of its four faces.
    const Vec4d* h = reinterpret_cast<const Vec4d*>(H + static_cast<size_t>(kGroupStride) * g);
    Vec4d* t = reinterpret_cast<Vec4d*>(local + static_cast<size_t>(kGroupStride) * g);
    Vec4d T[9];
    for (int e = 0; e < 9; ++e) T[e] = t[e];
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) {  // (T H^T)(r,c) = sum_j T(r,j) H(c,j)
        t[r + 3 * c] = T[r] * h[c] + T[r + 3] * h[c + 3] + T[r + 6] * h[c + 6];
      }
    }
  }
}
void condense_base(const double* H, double* local, int gb, int ge) {
  condense_body(H, local, gb, ge);
}
MD_TARGET_AVX2 void condense_avx2(const double* H, double* local, int gb, int ge) {
  condense_body(H, local, gb, ge);
}

// Right-hand side in the solver's permuted 4-wide layout, for free vertices [b, e): free vertex
// f goes to row free_row[f] and is the sum of f's terms (a term is a column of a face's T * H^T:
// three doubles 4 apart in the grouped layout) minus its coupling to the fixed vertices,
// K_fp.row(f) * fixed_pos (K_fp in CSR: kp, ki, kx; fixed_pos column-major with nfix rows).
// Walked in vertex order, not row order: meshes list faces roughly in vertex order, so the reads
// of `local` (36 doubles per 4 faces, larger than L2) stream, and the scattered writes land in
// the right-hand side, which is 4 doubles per vertex and stays in cache.
struct GatherArgs {
  const int *offset, *slot, *free_row;
  const double* local;
  const int *kp, *ki;
  const double *kx, *fixed_pos;
  int nfix;
  double* y4;
};
MD_ALWAYS_INLINE void gather_body(const GatherArgs& a, int b, int e) {
  for (int f = b; f < e; ++f) {
    double x = 0.0, y = 0.0, z = 0.0;
    for (int s = a.offset[f]; s < a.offset[f + 1]; ++s) {
      const double* t = a.local + a.slot[s];
      x += t[0];
      y += t[4];
      z += t[8];
    }
    for (int q = a.kp[f]; q < a.kp[f + 1]; ++q) {
      const double k = a.kx[q];
      const double* p = a.fixed_pos + a.ki[q];
      x -= k * p[0];
      y -= k * p[a.nfix];
      z -= k * p[2 * a.nfix];
    }
    double* r = a.y4 + 4 * static_cast<size_t>(a.free_row[f]);
    r[0] = x;
    r[1] = y;
    r[2] = z;
    r[3] = 0.0;
  }
}
void gather_base(const GatherArgs& a, int b, int e) { gather_body(a, b, e); }
MD_TARGET_AVX2 void gather_avx2(const GatherArgs& a, int b, int e) { gather_body(a, b, e); }
}  // namespace

struct PoissonRepositioner::Impl {
  int n = 0, m = 0;
  Vertices rest;
  Faces faces;
  std::vector<char> usable;
  // Per usable face: psi * (G_v - m_v4 g_4^T / mu), the condensed right-hand-side operator, in
  // the grouped layout (types.hpp; zero for unusable faces and padding). Row l is the
  // contribution of local vertex l: rhs_l = H.row(l) * T^T, i.e. column l of T * H^T, which is
  // what `local` holds per face during a solve.
  std::vector<double> H;
  std::vector<int> free_index;  // n; -1 for fixed vertices
  std::vector<int> free_verts;  // free vertex ids in unknown order
  std::vector<int> fixed_all;   // user fixed, then loose vertices, then gauge vertices
  int num_user_fixed = 0;
  Eigen::SparseMatrix<double, Eigen::RowMajor> K_fp;  // free x fixed_all coupling
  std::unique_ptr<SparseCholesky> chol;
  // Per free vertex (CSR): index into `local` of each of its terms (column l of a face's T H^T).
  std::vector<int> inc_offset, inc_slot;
  // Components solved only up to translation: restore their rest vertex mean afterwards.
  std::vector<int> gauge_comp_of;  // n; -1 when the vertex's component has a fixed vertex
  std::vector<Eigen::Vector3d> gauge_rest_mean;
  std::vector<double> gauge_count;

  // The solver's row order: free vertex f is permuted row free_row[f].
  std::vector<int> free_row;

  mutable std::mutex mutex;           // guards the workspace below
  mutable std::vector<double> local;  // grouped layout, kGroupStride per group
  mutable std::vector<double> y4;     // right-hand side, then solution, (nf,4) permuted rows
  mutable Col3 fixed_pos;
};

PoissonRepositioner::PoissonRepositioner(const Vertices& vertices, const Faces& faces,
                                         const Eigen::VectorXd& shear,
                                         const std::vector<int>& fixed)
    : impl_(std::make_unique<Impl>()), fixed_(fixed) {
  Impl& d = *impl_;
  d.n = static_cast<int>(vertices.rows());
  d.m = static_cast<int>(faces.rows());
  d.rest = vertices;
  d.faces = faces;
  if (shear.size() != d.m) throw std::invalid_argument("shear: one value per face expected");
  validate_mesh(vertices, faces);
  check_stiffness(shear.data(), shear.size(), "shear");

  std::vector<char> is_fixed(d.n, 0);
  for (int v : fixed) {
    if (v < 0 || v >= d.n) {
      throw std::invalid_argument("pinned vertex " + std::to_string(v) + " out of range");
    }
    if (is_fixed[v])
      throw std::invalid_argument("pinned vertex " + std::to_string(v) + " repeated");
    is_fixed[v] = 1;
  }

  // Local condensed matrices per face.
  if (d.m > (std::numeric_limits<int>::max() - kGroupStride) / 9) {
    throw std::invalid_argument("faces: too many for 32-bit offsets");
  }
  d.usable.assign(d.m, 0);
  d.H.assign(static_cast<size_t>(kGroupStride) * num_groups(d.m), 0.0);
  std::vector<Eigen::Matrix3d> Kloc(d.m, Eigen::Matrix3d::Zero());
  for (int i = 0; i < d.m; ++i) {
    const Eigen::Vector3d a = vertices.row(faces(i, 0)), b = vertices.row(faces(i, 1)),
                          c = vertices.row(faces(i, 2));
    const double longest2 =
        std::max({(b - a).squaredNorm(), (c - b).squaredNorm(), (a - c).squaredNorm()});
    const double dbl_area = (b - a).cross(c - a).norm();
    // Needles and zero-area faces have no usable frame; their vertices are placed by neighbours.
    if (!(longest2 > 0.0) || !(dbl_area > 1e-12 * longest2)) continue;
    const Eigen::Matrix3d E = face_frame(a, b, c).inverse();
    Eigen::Matrix<double, 4, 3> G;
    G.row(0) = -(E.row(0) + E.row(1) + E.row(2));
    G.row(1) = E.row(0);
    G.row(2) = E.row(1);
    G.row(3) = E.row(2);
    const double psi = shear(i);
    const Eigen::Matrix4d M = psi * G * G.transpose();
    const double mu = M(3, 3);
    const Eigen::Vector3d mv4 = M.block<3, 1>(0, 3);
    Kloc[i] = M.topLeftCorner<3, 3>() - mv4 * mv4.transpose() / mu;
    const Eigen::Matrix3d Hi = psi * (G.topRows<3>() - mv4 * G.row(3) / mu);
    for (int e = 0; e < 9; ++e) d.H[group_index(i, e)] = Hi.data()[e];
    d.usable[i] = 1;
  }

  if (std::find(d.usable.begin(), d.usable.end(), 1) == d.usable.end()) {
    throw std::invalid_argument("faces: every face is degenerate (zero area); nothing to solve");
  }

  // Components over usable faces; loose vertices (no usable face) keep their rest position.
  DisjointSets sets(d.n);
  std::vector<char> touched(d.n, 0);
  for (int i = 0; i < d.m; ++i) {
    if (!d.usable[i]) continue;
    for (int l = 0; l < 3; ++l) touched[faces(i, l)] = 1;
    sets.unite(faces(i, 0), faces(i, 1));
    sets.unite(faces(i, 0), faces(i, 2));
  }
  std::vector<char> root_has_fixed(d.n, 0);
  for (int v = 0; v < d.n; ++v) {
    if (is_fixed[v]) root_has_fixed[sets.find(v)] = 1;
  }

  d.fixed_all = fixed;
  d.num_user_fixed = static_cast<int>(fixed.size());
  for (int v = 0; v < d.n; ++v) {
    if (!is_fixed[v] && !touched[v]) {
      is_fixed[v] = 1;
      d.fixed_all.push_back(v);
    }
  }
  d.gauge_comp_of.assign(d.n, -1);
  std::vector<int> root_gauge(d.n, -1);
  for (int v = 0; v < d.n; ++v) {
    if (!touched[v]) continue;
    const int r = sets.find(v);
    if (root_has_fixed[r]) continue;
    if (root_gauge[r] < 0) {
      // Lowest vertex of the component anchors its translation during the solve.
      root_gauge[r] = static_cast<int>(d.gauge_rest_mean.size());
      d.gauge_rest_mean.push_back(Eigen::Vector3d::Zero());
      d.gauge_count.push_back(0.0);
      is_fixed[v] = 1;
      d.fixed_all.push_back(v);
    }
    const int g = root_gauge[r];
    d.gauge_comp_of[v] = g;
    d.gauge_rest_mean[g] += vertices.row(v).transpose();
    d.gauge_count[g] += 1.0;
  }
  for (size_t g = 0; g < d.gauge_rest_mean.size(); ++g) d.gauge_rest_mean[g] /= d.gauge_count[g];

  d.free_index.assign(d.n, -1);
  for (int v = 0; v < d.n; ++v) {
    if (!is_fixed[v]) {
      d.free_index[v] = static_cast<int>(d.free_verts.size());
      d.free_verts.push_back(v);
    }
  }
  std::vector<int> fixed_slot(d.n, -1);
  for (size_t s = 0; s < d.fixed_all.size(); ++s) fixed_slot[d.fixed_all[s]] = static_cast<int>(s);

  const int nf = static_cast<int>(d.free_verts.size());
  std::vector<Eigen::Triplet<double>> kff, kfp;
  kff.reserve(static_cast<size_t>(6 * d.m));
  for (int i = 0; i < d.m; ++i) {
    if (!d.usable[i]) continue;
    for (int r = 0; r < 3; ++r) {
      const int fr = d.free_index[faces(i, r)];
      if (fr < 0) continue;
      for (int c = 0; c < 3; ++c) {
        const int vc = faces(i, c);
        const int fc = d.free_index[vc];
        if (fc >= 0) {
          if (fc <= fr) kff.emplace_back(fr, fc, Kloc[i](r, c));
        } else {
          kfp.emplace_back(fr, fixed_slot[vc], Kloc[i](r, c));
        }
      }
    }
  }
  Eigen::SparseMatrix<double> Kff(nf, nf);
  Kff.setFromTriplets(kff.begin(), kff.end());
  d.K_fp.resize(nf, static_cast<Eigen::Index>(d.fixed_all.size()));
  d.K_fp.setFromTriplets(kfp.begin(), kfp.end());
  d.K_fp.makeCompressed();  // solve() reads its CSR arrays
  d.chol =
      std::make_unique<SparseCholesky>(Kff, SparseCholesky::Reuse::PerPose);  // solved per pose

  // Gather lists so right-hand-side assembly runs in parallel without write races.
  d.inc_offset.assign(nf + 1, 0);
  for (int i = 0; i < d.m; ++i) {
    if (!d.usable[i]) continue;
    for (int l = 0; l < 3; ++l) {
      const int f = d.free_index[faces(i, l)];
      if (f >= 0) ++d.inc_offset[f + 1];
    }
  }
  for (int f = 0; f < nf; ++f) d.inc_offset[f + 1] += d.inc_offset[f];
  d.inc_slot.resize(d.inc_offset[nf]);
  std::vector<int> cursor(d.inc_offset.begin(), d.inc_offset.end() - 1);
  for (int i = 0; i < d.m; ++i) {
    if (!d.usable[i]) continue;
    for (int l = 0; l < 3; ++l) {
      const int f = d.free_index[faces(i, l)];
      if (f >= 0) d.inc_slot[cursor[f]++] = static_cast<int>(group_index(i, 3 * l));
    }
  }

  d.local.assign(d.H.size(), 0.0);
  const std::vector<int> row_free = d.chol->permutation();  // row i is free vertex row_free[i]
  d.free_row.resize(row_free.size());
  for (size_t i = 0; i < row_free.size(); ++i) d.free_row[row_free[i]] = static_cast<int>(i);
  d.y4.assign(4 * static_cast<size_t>(nf), 0.0);
  d.fixed_pos.resize(static_cast<Eigen::Index>(d.fixed_all.size()), 3);
  for (size_t s = d.num_user_fixed; s < d.fixed_all.size(); ++s) {
    d.fixed_pos.row(static_cast<Eigen::Index>(s)) = vertices.row(d.fixed_all[s]);
  }
}

PoissonRepositioner::~PoissonRepositioner() = default;

int PoissonRepositioner::num_unknowns() const { return static_cast<int>(impl_->free_verts.size()); }

int PoissonRepositioner::substitution_threads() const {
  return impl_->chol ? impl_->chol->substitution_threads() : 0;
}

void PoissonRepositioner::solve(const Matrix3Array& targets, const Vertices& fixed_positions,
                                Vertices* out) const {
  if (static_cast<int>(targets.size()) != impl_->m) {
    throw std::invalid_argument("one target transform per face expected");
  }
  const int m = impl_->m;
  solve(
      [&](int gb, int ge, double* T) {
        for (int i = kGroupFaces * gb; i < std::min(kGroupFaces * ge, m); ++i) {
          for (int e = 0; e < 9; ++e)
            T[group_index(i, e) - group_index(kGroupFaces * gb, 0)] = targets[i].data()[e];
        }
      },
      fixed_positions, out);
}

void PoissonRepositioner::solve(const TargetBlocks& targets, const Vertices& fixed_positions,
                                Vertices* out) const {
  const Impl& d = *impl_;
  const std::lock_guard<std::mutex> lock(d.mutex);
  if (fixed_positions.rows() != d.num_user_fixed) {
    throw std::invalid_argument("pinned_positions: one row per pinned vertex expected");
  }
  const int nf = static_cast<int>(d.free_verts.size());

  // Each block of targets lands in `local` and is turned into its right-hand-side terms in place.
  const bool avx2 = cpu_has_avx2_fma();
  parallel_ranges(num_groups(d.m), 8192 / kGroupFaces, 8, [&](int gb, int ge) {
    targets(gb, ge, &d.local[static_cast<size_t>(kGroupStride) * gb]);
    (avx2 ? condense_avx2 : condense_base)(d.H.data(), d.local.data(), gb, ge);
  });
  if (d.num_user_fixed > 0) d.fixed_pos.topRows(d.num_user_fixed) = fixed_positions;
  const GatherArgs args{
      d.inc_offset.data(), d.inc_slot.data(),      d.free_row.data(),
      d.local.data(),      d.K_fp.outerIndexPtr(), d.K_fp.innerIndexPtr(),
      d.K_fp.valuePtr(),   d.fixed_pos.data(),     static_cast<int>(d.fixed_pos.rows()),
      d.y4.data()};
  parallel_ranges(nf, 4096, 8,
                  [&](int b, int e) { (avx2 ? gather_avx2 : gather_base)(args, b, e); });
  d.chol->solve_permuted4(d.y4.data());

  out->resize(d.n, 3);
  // Vertex order: sequential writes, reads from cached rows; distinct rows per range.
  parallel_ranges(nf, 8192, 8, [&](int b, int e) {
    for (int f = b; f < e; ++f) {
      const double* r = &d.y4[4 * static_cast<size_t>(d.free_row[f])];
      out->row(d.free_verts[f]) << r[0], r[1], r[2];
    }
  });
  for (size_t s = 0; s < d.fixed_all.size(); ++s) {
    out->row(d.fixed_all[s]) = d.fixed_pos.row(static_cast<Eigen::Index>(s));
  }
  if (!d.gauge_rest_mean.empty()) {
    std::vector<Eigen::Vector3d> mean(d.gauge_rest_mean.size(), Eigen::Vector3d::Zero());
    for (int v = 0; v < d.n; ++v) {
      const int g = d.gauge_comp_of[v];
      if (g >= 0) mean[g] += out->row(v).transpose();
    }
    for (size_t g = 0; g < mean.size(); ++g) {
      mean[g] = d.gauge_rest_mean[g] - mean[g] / d.gauge_count[g];
    }
    for (int v = 0; v < d.n; ++v) {
      const int g = d.gauge_comp_of[v];
      if (g >= 0) out->row(v) += mean[g].transpose();
    }
  }
}

}  // namespace matdeform
