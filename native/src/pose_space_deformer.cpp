// The pose-space deformer's pipeline (matdeform/pose_space_deformer.hpp): input checks, the
// bind (mesh parts, frame, handles, the solve level, the constraint sets and the solvers) and
// deform(): pose -> example weights -> blend -> step 1 (natural shape, rigid fits, rotations with
// the handles) -> step 2 -> dense positions. The parts of the method live in the files listed in
// pose_space_internal.hpp.
#include "matdeform/pose_space_deformer.hpp"

#include <Eigen/Dense>
#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <mutex>
#include <numeric>
#include <sstream>
#include <stdexcept>
#include <string>
#include <utility>

#include "matdeform/frames.hpp"
#include "matdeform/mesh.hpp"
#include "matdeform/transforms.hpp"
#include "pose_space_internal.hpp"
#include "task_pool.hpp"

namespace matdeform {
namespace pose_space {

double ms_since(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

[[noreturn]] void fail(const std::string& msg) { throw std::invalid_argument(msg); }

std::string item(const char* name, size_t i) {
  return std::string(name) + "[" + std::to_string(i) + "]";
}

std::string number(double x) {
  std::ostringstream s;
  s << x;
  return s.str();
}

Mat3 best_rotation(const Vertices& P, const Vertices& Q) {
  if (P.rows() == 0) return Mat3::Identity();
  const Eigen::RowVector3d pc = P.colwise().mean(), qc = Q.colwise().mean();
  const Mat3 H = (P.rowwise() - pc).transpose() * (Q.rowwise() - qc);
  Eigen::JacobiSVD<Mat3> svd(H, Eigen::ComputeFullU | Eigen::ComputeFullV);
  const Vec3 sv = svd.singularValues();
  if (!(sv(0) > 1e-300)) return Mat3::Identity();
  const Mat3 U = svd.matrixU(), V = svd.matrixV();
  if (sv(1) <= 1e-10 * sv(0)) {
    return Eigen::Quaterniond::FromTwoVectors(U.col(0), V.col(0)).toRotationMatrix();
  }
  Mat3 D = Mat3::Identity();
  if ((V * U.transpose()).determinant() < 0.0) D(2, 2) = -1.0;
  return V * D * U.transpose();
}

// Second singular value over the first of the centred point set: 0 for collinear points.
double planarity(const Vertices& P) {
  if (P.rows() < 3) return 0.0;
  const Eigen::RowVector3d c = P.colwise().mean();
  const Mat3 C = (P.rowwise() - c).transpose() * (P.rowwise() - c);
  Eigen::SelfAdjointEigenSolver<Mat3> es(C);
  const Vec3 ev = es.eigenvalues();  // ascending
  return ev(2) > 0.0 ? std::sqrt(std::max(ev(1), 0.0) / ev(2)) : 0.0;
}

Vertices gather_rows(const Vertices& X, const std::vector<int>& ids) {
  Vertices out(static_cast<Eigen::Index>(ids.size()), 3);
  for (size_t i = 0; i < ids.size(); ++i) out.row(static_cast<Eigen::Index>(i)) = X.row(ids[i]);
  return out;
}

// Rotation factor of the deformation gradient of one triangle, rest (a,b,c) -> (a2,b2,c2).
Mat3 face_rotation(const Mat3& rest_frame_inverse, const Vec3& a, const Vec3& b, const Vec3& c) {
  Mat3 S, R;
  polar_decompose(face_frame(a, b, c) * rest_frame_inverse, &S, &R);
  return R;
}

namespace {

bool lex_less(const Vec3& a, const Vec3& b) {
  return std::lexicographical_compare(a.data(), a.data() + 3, b.data(), b.data() + 3);
}

}  // namespace

Vec3 centroid(const Vertices& V, int a, int b, int c) {
  std::array<Vec3, 3> p = {V.row(a).transpose(), V.row(b).transpose(), V.row(c).transpose()};
  std::sort(p.begin(), p.end(), lex_less);
  return (p[0] + p[1] + p[2]) / 3.0;
}

// Mean of the rows `ids` of V, summed in lexicographic order of the points (the same bits for
// any numbering).
Vec3 canonical_mean(const Vertices& V, std::vector<int> ids) {
  std::sort(ids.begin(), ids.end(),
            [&](int a, int b) { return lex_less(V.row(a).transpose(), V.row(b).transpose()); });
  Vec3 sum = Vec3::Zero();
  for (int i : ids) sum += V.row(i).transpose();
  return sum / static_cast<double>(std::max<size_t>(ids.size(), 1));
}

// The face whose rest centroid is nearest to `point` (ties: lexicographic centroid), a choice
// that does not depend on the numbering of faces or vertices. Among the faces in `candidates`
// (-1 when it is empty).
int nearest_face(const Vertices& V, const Faces& F, const Vec3& point,
                 const std::vector<int>& candidates) {
  int best = -1;
  double bd = 0.0;
  Vec3 bc = Vec3::Zero();
  for (const int f : candidates) {
    const Vec3 c = centroid(V, F(f, 0), F(f, 1), F(f, 2));
    const double d = (c - point).squaredNorm();
    const bool better = best < 0 || d < bd || (d == bd && lex_less(c, bc));
    if (better) {
      best = f;
      bd = d;
      bc = c;
    }
  }
  return best;
}

}  // namespace pose_space

using namespace pose_space;  // NOLINT: this file is part of the method

std::optional<double> PoseSpaceDeformer::Impl::beyond_reach(const Vec3& x) const {
  const double d = (x - center).cwiseAbs().maxCoeff();
  if (d > kMaxReach * diag) return d;
  return std::nullopt;
}

void PoseSpaceDeformer::Impl::check_reach(const Vertices& X, const std::string& what) const {
  for (Eigen::Index i = 0; i < X.rows(); ++i) {
    if (const auto d = beyond_reach(X.row(i).transpose())) {
      fail(what + ": row " + std::to_string(i) + " lies " + number(*d) +
           " from the rest mesh, over " + number(kMaxReach) +
           " times its size; rescale the mesh and the positions (only shapes matter)");
    }
  }
}

void PoseSpaceDeformer::Impl::check_inputs(const std::vector<Vertices>& hp,
                                           const Matrix3Array* rotations,
                                           const Eigen::Matrix4d* frame_transform,
                                           const Vectors3* rotation_vectors) const {
  if (static_cast<int>(hp.size()) != h) {
    fail("handle_positions: expected " + std::to_string(h) + " arrays, got " +
         std::to_string(hp.size()));
  }
  for (int j = 0; j < h; ++j) {
    const int k = handle_offset[j + 1] - handle_offset[j];
    if (hp[j].rows() != k) {
      fail(item("handle_positions", j) + ": expected shape (" + std::to_string(k) + ",3), got (" +
           std::to_string(hp[j].rows()) + ",3)");
    }
    if (!hp[j].allFinite()) fail(item("handle_positions", j) + ": contains NaN or infinity");
    check_reach(hp[j], item("handle_positions", j));
  }
  if (rotations) {
    if (static_cast<int>(rotations->size()) != r) {
      fail("rotations: expected " + std::to_string(r) + " rotations, got " +
           std::to_string(rotations->size()));
    }
    for (int q = 0; q < r; ++q) {
      const Mat3& G = (*rotations)[q];
      if (!G.allFinite() || !(G.transpose() * G).isIdentity(1e-6) || G.determinant() < 0.0) {
        fail(item("rotations", q) + ": expected a rotation matrix (orthonormal, det +1)");
      }
    }
  }
  if (frame_transform) {
    if (frame < 0) fail("frame_transform: given, but the deformer has no frame face");
    const Eigen::Matrix4d& T = *frame_transform;
    const Mat3 Rf = T.topLeftCorner<3, 3>();
    if (!T.allFinite() || !(Rf.transpose() * Rf).isIdentity(1e-6) || Rf.determinant() < 0.0 ||
        !T.row(3).isApprox(Eigen::RowVector4d(0, 0, 0, 1), 1e-12)) {
      fail(
          "frame_transform: expected a rigid 4x4 transform (rotation, translation, bottom row "
          "0 0 0 1)");
    }
    if (const auto d = beyond_reach(Rf * frame_rest_centroid + T.topRightCorner<3, 1>())) {
      fail("frame_transform: moves the frame face " + number(*d) + " from the rest mesh, over " +
           number(kMaxReach) +
           " times its size; rescale the mesh and the positions (only shapes matter)");
    }
  } else if (frame >= 0 && p >= 2 &&
             (frame_in_handles[0] < 0 || frame_in_handles[1] < 0 || frame_in_handles[2] < 0)) {
    fail(
        "frame_transform: required, because the vertices of the frame face are not all handle "
        "vertices");
  }
  if (rotation_vectors) check_rotation_vectors(hp, rotations, *rotation_vectors);
}

// Each row a log of its anchor's rotation: the handle's fitted one (where defined) or the joint's.
void PoseSpaceDeformer::Impl::check_rotation_vectors(const std::vector<Vertices>& hp,
                                                     const Matrix3Array* rotations,
                                                     const Vectors3& v) const {
  if (v.rows() != h + r) {
    fail("rotation_vectors: expected shape (" + std::to_string(h + r) + ",3), one per handle (" +
         std::to_string(h) + ") then one per rotational pair (" + std::to_string(r) + "), got " +
         std::to_string(v.rows()) + " rows");
  }
  auto check = [&](int row, const Mat3& R, double tolerance, const std::string& what) {
    const Vec3 vr = v.row(row).transpose();
    const std::string name = item("rotation_vectors", row);
    if (!vr.allFinite()) fail(name + ": contains NaN or infinity");
    const double err = rotation_vector_mismatch(vr, R);
    if (err <= tolerance) return;
    std::ostringstream msg;
    msg << name << ": its exp differs from " << what << " by " << err << " rad (tolerance "
        << tolerance
        << "); expected a log of that rotation, i.e. its principal log plus whole turns about "
           "the same axis";
    if (std::isnan(err)) msg << " (this vector, " << vr.norm() << " rad, is too long)";
    fail(msg.str());
  };
  for (int j = 0; j < h; ++j) {
    const int b = handle_offset[j], e = handle_offset[j + 1];
    const Vertices rest_j = handle_rest.middleRows(b, e - b);
    if (e - b < 3 || !(planarity(rest_j) > 1e-6) || !(planarity(hp[j]) > 1e-6)) {
      // no rotation to compare with (and none for step 1 to take): the row must be finite
      if (!v.row(j).allFinite()) fail(item("rotation_vectors", j) + ": contains NaN or infinity");
      continue;
    }
    check(j, best_rotation(rest_j, hp[j]), kHandleVectorTolerance,
          "the rotation of handle " + std::to_string(j) + " (its best rigid fit, rest -> " +
              item("handle_positions", static_cast<size_t>(j)) + ")");
  }
  for (int q = 0; q < r; ++q) {
    if (rotations) {
      check(h + q, (*rotations)[q], kRotationVectorTolerance, item("rotations", q));
    } else if (!v.row(h + q).allFinite()) {  // joints free: the row is not used
      fail(item("rotation_vectors", h + q) + ": contains NaN or infinity");
    }
  }
}

Vertices PoseSpaceDeformer::Impl::concat_targets(const std::vector<Vertices>& hp) const {
  Vertices t(static_cast<Eigen::Index>(handle_all.size()), 3);
  for (int j = 0; j < h; ++j) t.middleRows(handle_offset[j], hp[j].rows()) = hp[j];
  return t;
}

// ------------------------------------------------------------------------------------------

PoseSpaceDeformer::PoseSpaceDeformer(const Vertices& vertices, const Faces& faces,
                                     const std::vector<Vertices>& examples,
                                     const std::vector<std::vector<int>>& handles,
                                     const PoseSpaceOptions& options)
    : impl_(std::make_unique<Impl>()) {
  Impl& I = *impl_;
  validate_mesh(vertices, faces);
  I.rest = vertices;
  I.faces = faces;
  I.opt = options;
  I.n = static_cast<int>(vertices.rows());
  I.m = static_cast<int>(faces.rows());
  I.p = static_cast<int>(examples.size());
  I.h = static_cast<int>(handles.size());
  I.r = static_cast<int>(options.rotational.size());
  const int n = I.n, m = I.m;
  if (m == 0) fail("faces: expected at least one triangle");
  {
    std::vector<char> used(n, 0);
    for (int f = 0; f < m; ++f)
      for (int l = 0; l < 3; ++l) used[faces(f, l)] = 1;
    for (int v = 0; v < n; ++v) {
      if (!used[v]) fail("vertices: vertex " + std::to_string(v) + " is not used by any face");
    }
  }
  const DualEdges dual = dual_edges(faces);
  I.diag = (vertices.colwise().maxCoeff() - vertices.colwise().minCoeff()).norm();
  I.center = (vertices.colwise().minCoeff() +
              0.5 * (vertices.colwise().maxCoeff() - vertices.colwise().minCoeff()))
                 .transpose();
  if (!(options.position_weight > 0.0) || !std::isfinite(options.position_weight)) {
    fail("position_weight: expected a finite value > 0");
  }
  if (!(options.rotation_weight > 0.0) || !std::isfinite(options.rotation_weight)) {
    fail("rotation_weight: expected a finite value > 0");
  }
  if (!(options.joint_weight > 0.0) || !std::isfinite(options.joint_weight)) {
    fail("joint_weight: expected a finite value > 0");
  }
  if (!(options.weight_regularization >= 0.0) || !std::isfinite(options.weight_regularization)) {
    fail("weight_regularization: expected a finite value >= 0");
  }
  if (options.transfer_neighbors < 1) fail("transfer_neighbors: expected >= 1");
  if (options.rotation_iterations < 1) fail("rotation_iterations: expected >= 1");
  if (options.gauge_steps < 1) fail("gauge_steps: expected >= 1");
  if (!(options.rotation_tolerance > 0.0) || !(options.rotation_tolerance < 1.0)) {
    fail("rotation_tolerance: expected a value in (0, 1)");
  }
  if (!(options.reliability_angle > 0.0)) fail("reliability_angle: expected a value > 0");
  if (!(options.orientation_weight >= 0.0) || !std::isfinite(options.orientation_weight)) {
    fail("orientation_weight: expected a finite value >= 0");
  }

  // Examples.
  for (int k = 0; k < I.p; ++k) {
    if (examples[k].rows() != n) {
      fail(item("examples", k) + ": expected shape (" + std::to_string(n) + ",3), got (" +
           std::to_string(examples[k].rows()) + ",3)");
    }
    if (!examples[k].allFinite()) fail(item("examples", k) + ": contains NaN or infinity");
    I.check_reach(examples[k], item("examples", k));
  }

  // Handles: non-empty, in range, unique, disjoint.
  I.handles = handles;
  std::vector<int> owner(n, -1);
  I.handle_offset.push_back(0);
  for (int j = 0; j < I.h; ++j) {
    if (handles[j].empty()) fail(item("handles", j) + ": a handle needs at least one vertex");
    for (int v : handles[j]) {
      if (v < 0 || v >= n) {
        fail(item("handles", j) + ": vertex " + std::to_string(v) + " outside [0, " +
             std::to_string(n) + ")");
      }
      if (owner[v] == j) fail(item("handles", j) + ": vertex " + std::to_string(v) + " repeated");
      if (owner[v] >= 0) {
        fail("handles: handles " + std::to_string(owner[v]) + " and " + std::to_string(j) +
             " share vertex " + std::to_string(v));
      }
      owner[v] = j;
      I.handle_all.push_back(v);
    }
    I.handle_offset.push_back(static_cast<int>(I.handle_all.size()));
  }
  I.handle_rest = gather_rows(vertices, I.handle_all);

  // Frozen faces.
  I.is_frozen_vertex.assign(n, 0);
  {
    std::vector<char> seen(m, 0);
    for (size_t q = 0; q < options.frozen.size(); ++q) {
      const int f = options.frozen[q];
      if (f < 0 || f >= m) {
        fail("frozen: face " + std::to_string(f) + " outside [0, " + std::to_string(m) + ")");
      }
      if (seen[f]) fail("frozen: face " + std::to_string(f) + " repeated");
      seen[f] = 1;
      for (int l = 0; l < 3; ++l) I.is_frozen_vertex[faces(f, l)] = 1;
    }
    for (int v = 0; v < n; ++v) {
      if (I.is_frozen_vertex[v]) I.frozen_vertices.push_back(v);
    }
    for (int v : I.handle_all) {
      if (I.is_frozen_vertex[v]) {
        fail("handles: vertex " + std::to_string(v) +
             " belongs to a frozen face, which keeps its rest position");
      }
    }
  }

  // Frame face.
  if (options.frame) {
    const int f = *options.frame;
    if (f < 0 || f >= m) {
      fail("frame: face " + std::to_string(f) + " outside [0, " + std::to_string(m) + ")");
    }
    I.frame = f;
    std::vector<int> pos(n, -1);
    for (size_t s = 0; s < I.handle_all.size(); ++s) pos[I.handle_all[s]] = static_cast<int>(s);
    for (int l = 0; l < 3; ++l) {
      I.frame_vertices[l] = faces(f, l);
      I.frame_in_handles[l] = pos[faces(f, l)];
    }
    const Vec3 a = vertices.row(faces(f, 0)), b = vertices.row(faces(f, 1)),
               c = vertices.row(faces(f, 2));
    I.frame_rest_inverse = face_frame(a, b, c).inverse();
    I.frame_rest_centroid = (a + b + c) / 3.0;
  }

  // Rotational pairs.
  for (int q = 0; q < I.r; ++q) {
    const auto& pr = options.rotational[q];
    for (int s = 0; s < 2; ++s) {
      if (pr[s] < 0 || pr[s] >= m) {
        fail(item("rotational", q) + ": face " + std::to_string(pr[s]) + " outside [0, " +
             std::to_string(m) + ")");
      }
    }
    if (pr[0] == pr[1]) fail(item("rotational", q) + ": the two faces must differ");
  }

  // Parts (vertices connected through edges): those with a control are solved, the others
  // stay exactly at rest.
  {
    DisjointSets sets(n);
    for (int f = 0; f < m; ++f) {
      sets.unite(faces(f, 0), faces(f, 1));
      sets.unite(faces(f, 0), faces(f, 2));
    }
    std::vector<int> label(n, -1);
    I.vpart.resize(n);
    I.parts = 0;
    for (int v = 0; v < n; ++v) {
      const int root = sets.find(v);
      if (label[root] < 0) label[root] = I.parts++;
      I.vpart[v] = label[root];
    }
  }
  std::vector<int> fpart(m);
  for (int f = 0; f < m; ++f) fpart[f] = I.vpart[faces(f, 0)];
  std::vector<char> controlled(I.parts, 0);
  I.part_frozen.assign(I.parts, 0);
  for (int v : I.handle_all) controlled[I.vpart[v]] = 1;
  for (int f : options.frozen) controlled[fpart[f]] = I.part_frozen[fpart[f]] = 1;
  if (I.frame >= 0) controlled[fpart[I.frame]] = 1;
  for (const auto& pr : options.rotational) controlled[fpart[pr[0]]] = controlled[fpart[pr[1]]] = 1;
  I.at_rest.assign(n, 0);
  for (int v = 0; v < n; ++v) I.at_rest[v] = I.is_frozen_vertex[v] || !controlled[I.vpart[v]];
  Faces afaces;  // faces of the solved parts, in dense order
  std::vector<int> aface_ids;
  for (int f = 0; f < m; ++f) {
    if (controlled[fpart[f]]) aface_ids.push_back(f);
  }
  I.whole = static_cast<int>(aface_ids.size()) == m;
  if (I.whole) {
    afaces = faces;
  } else {
    afaces.resize(static_cast<Eigen::Index>(aface_ids.size()), 3);
    for (size_t i = 0; i < aface_ids.size(); ++i)
      afaces.row(static_cast<Eigen::Index>(i)) = faces.row(aface_ids[i]);
  }
  int active_vertices = 0;
  for (int v = 0; v < n; ++v) active_vertices += controlled[I.vpart[v]];

  // Pose space.
  if (options.orientation_weight > 0.0) {
    for (int j = 0; j < I.h; ++j) {
      const int b = I.handle_offset[j], e = I.handle_offset[j + 1];
      if (e - b >= 3 && planarity(I.handle_rest.middleRows(b, e - b)) > 1e-3)
        I.oriented.push_back(j);
    }
  }
  if (I.p >= 2) {
    if (I.h == 0 && I.r == 0) {
      fail(
          "handles: with two or more examples the pose must be measured from at least one handle "
          "or rotational pair");
    }
    const bool own_frame = I.frame < 0 && I.frozen_vertices.empty();
    if (I.h == 1 && own_frame && I.r == 0) {
      fail(
          "handles: a single handle measured in its own best-fit frame says nothing about the "
          "pose; add handles, a frame face, a frozen region or rotational pairs");
    }
    if (I.h > 0 && own_frame && planarity(I.handle_rest) < 1e-6) {
      fail(
          "handles: the handle vertices lie on a line, so the frame the pose is measured in is "
          "undefined; add handle vertices off that line or give a frame face");
    }
    try {
      for (int k = 0; k < I.p; ++k) {
        // Checked here so that a degenerate face reports the example.
        if (I.frame >= 0) (void)I.example_face_rotation(examples[k], I.frame);
        for (const auto& pr : options.rotational) {
          (void)I.example_face_rotation(examples[k], pr[0]);
          (void)I.example_face_rotation(examples[k], pr[1]);
        }
      }
    } catch (const std::invalid_argument&) {
      fail("examples: a frame or rotational face is degenerate in an example");
    }
    if (I.r > 0) {
      RowMatrix P(I.p, I.pose_dim(true));
      for (int k = 0; k < I.p; ++k) P.row(k) = I.example_pose(examples[k], true).transpose();
      I.interp_full = Interpolator(P, options.weight_regularization, options.convex_weights);
    }
    if (I.h == 0) {
      I.positions_error =
          "rotations: required, because without handles the pose is given by the joint rotations "
          "alone";
    } else {
      RowMatrix P(I.p, I.pose_dim(false));
      for (int k = 0; k < I.p; ++k) P.row(k) = I.example_pose(examples[k], false).transpose();
      try {
        I.interp_positions = Interpolator(P, options.weight_regularization, options.convex_weights);
      } catch (const std::invalid_argument& e) {
        if (I.r == 0) throw;
        I.positions_error =
            std::string("rotations: required to tell the examples apart (") + e.what() + ")";
      }
    }
  }

  // Solve level.
  if (options.coarse_faces && (*options.coarse_faces < 4 || *options.coarse_faces >= m)) {
    fail("coarse: expected a face count in [4, " + std::to_string(m) + "), got " +
         std::to_string(*options.coarse_faces));
  }
  if (aface_ids.empty()) return;  // no part has a control: deform() returns the rest mesh
  if (options.coarse_faces) {
    const int target = *options.coarse_faces;
    if (target >= afaces.rows()) {
      fail("coarse: expected fewer faces than the " + std::to_string(afaces.rows()) +
           " of the parts being solved (the parts without a control stay at rest), got " +
           std::to_string(target));
    }
    // meshopt takes float positions: beyond ~3e38 they are infinite.
    const double far = vertices.cwiseAbs().maxCoeff();
    if (!(far < 1e37)) {
      fail("coarse: the mesh lies " + number(far) +
           " from the origin and the simplifier works in single precision; move the mesh nearer "
           "the origin or solve at full resolution");
    }
    I.multires = true;
    I.whole = false;
    coarse_mesh(vertices, afaces, target, I.diag, &I.lvertices, &I.lrest, &I.lfaces);
  } else if (I.whole) {
    I.lrest = vertices;
    I.lfaces = faces;
    I.lvertices.resize(n);
    std::iota(I.lvertices.begin(), I.lvertices.end(), 0);
  } else {
    for (int v = 0; v < n; ++v) {
      if (controlled[I.vpart[v]]) I.lvertices.push_back(v);
    }
    I.lrest = gather_rows(vertices, I.lvertices);
  }
  const int ln = static_cast<int>(I.lvertices.size());
  I.level_of.assign(n, -1);
  for (int c = 0; c < ln; ++c) I.level_of[I.lvertices[c]] = c;
  const std::vector<int>& level_of = I.level_of;
  std::vector<int> lface_of;  // single resolution: dense face -> level face
  if (!I.multires && !I.whole) {
    I.lfaces.resize(afaces.rows(), 3);
    lface_of.assign(m, -1);
    for (Eigen::Index f = 0; f < afaces.rows(); ++f) {
      for (int l = 0; l < 3; ++l) I.lfaces(f, l) = level_of[afaces(f, l)];
      lface_of[aface_ids[f]] = static_cast<int>(f);
    }
  }
  const int lm = static_cast<int>(I.lfaces.rows());
  I.ldual = I.whole ? dual.pairs : dual_edges(I.lfaces).pairs;
  I.lface_part.resize(lm);
  for (int f = 0; f < lm; ++f) I.lface_part[f] = I.vpart[I.lvertices[I.lfaces(f, 0)]];
  std::vector<int> lvpart(ln);
  for (int c = 0; c < ln; ++c) lvpart[c] = I.vpart[I.lvertices[c]];
  if (I.multires) {
    // Each solved part must come out as one piece of the coarse mesh.
    int count = 0;
    const std::vector<int> lcomp = face_components(lm, I.ldual, &count);
    std::vector<int> pieces(I.parts, 0), seen(count, 0);
    for (int f = 0; f < lm; ++f) {
      if (!seen[lcomp[f]]) ++pieces[I.lface_part[f]];
      seen[lcomp[f]] = 1;
    }
    for (int c = 0; c < I.parts; ++c) {
      if (!controlled[c] || pieces[c] == 1) continue;
      std::string which;
      for (int f = 0; f < m && which.empty(); ++f) {
        if (fpart[f] == c) which = "the part with face " + std::to_string(f);
      }
      fail("coarse: " + (I.parts == 1 ? std::string("the mesh") : which) +
           (pieces[c] == 0 ? " vanishes from the simplified mesh"
                           : " falls apart into " + std::to_string(pieces[c]) + " pieces") +
           "; choose a larger face count");
    }
  }

  if (I.multires) I.build_transfer(afaces);

  // Encodings of the examples on the level (pose_space_encoding.cpp).
  std::vector<Matrix3Array> example_rotations;
  I.encode_examples(examples, &example_rotations);
  const int E = static_cast<int>(I.ldual.rows());

  if (I.multires) I.build_details(examples, example_rotations);

  // Level constraint sets.
  std::vector<char> lface_frozen(lm, 0);
  for (int c = 0; c < ln; ++c) {
    if (I.is_frozen_vertex[I.lvertices[c]]) I.lfixed_vertices.push_back(c);
  }
  if (!I.multires) {
    for (int f : options.frozen) lface_frozen[I.whole ? f : lface_of[f]] = 1;
  } else {
    for (int f = 0; f < lm; ++f) {
      lface_frozen[f] = I.is_frozen_vertex[I.lvertices[I.lfaces(f, 0)]] &&
                        I.is_frozen_vertex[I.lvertices[I.lfaces(f, 1)]] &&
                        I.is_frozen_vertex[I.lvertices[I.lfaces(f, 2)]];
    }
  }
  for (int f = 0; f < lm; ++f) {
    if (lface_frozen[f]) I.lfixed_faces.push_back(f);
  }
  if (!options.frozen.empty() && I.lfixed_faces.empty()) {
    fail(
        "frozen: the frozen region contains no face of the coarse mesh; enlarge it or use a "
        "larger coarse face count");
  }
  std::vector<std::vector<int>> part_members(I.parts), lpart_faces(I.parts);
  for (int v = 0; v < n; ++v) part_members[I.vpart[v]].push_back(v);
  for (int f = 0; f < lm; ++f) lpart_faces[I.lface_part[f]].push_back(f);
  // Rotational pairs on the level.
  for (int q = 0; q < I.r; ++q) {
    std::array<int, 2> lp;
    for (int s = 0; s < 2; ++s) {
      const int f = options.rotational[q][s];
      const Vec3 c = centroid(vertices, faces(f, 0), faces(f, 1), faces(f, 2));
      lp[s] = I.multires ? nearest_face(I.lrest, I.lfaces, c, lpart_faces[fpart[f]])
              : I.whole  ? f
                         : lface_of[f];
    }
    if (lp[0] == lp[1]) {
      fail(item("rotational", q) +
           ": both faces fall on the same coarse face; use a larger "
           "coarse face count");
    }
    I.lpairs.push_back(lp);
  }
  // Faces under each handle: single resolution, faces with all corners in the handle;
  // multiresolution, coarse faces whose corners are handle vertices or the strongest coarse
  // neighbour of one.
  if (options.handle_rotations) {
    std::vector<int> lowner(ln, -1);
    for (int j = 0; j < I.h; ++j) {
      for (int v : handles[j]) {
        if (level_of[v] >= 0 && lowner[level_of[v]] < 0) lowner[level_of[v]] = j;
        // The strongest coarse neighbour: the transfer weights come best first, weights tied
        // within round-off ordered by the coarse vertex, not by which round-off is larger.
        if (I.multires && I.tr_ptr[v + 1] > I.tr_ptr[v]) {
          const int best = I.tr_idx[I.tr_ptr[v]];
          if (lowner[best] < 0) lowner[best] = j;
        }
      }
    }
    for (int f = 0; f < lm; ++f) {
      const int j = lowner[I.lfaces(f, 0)];
      if (j >= 0 && lowner[I.lfaces(f, 1)] == j && lowner[I.lfaces(f, 2)] == j &&
          !lface_frozen[f]) {
        I.lhandle_faces.push_back(f);
        I.lhandle_owner.push_back(j);
      }
    }
  }

  // Solvers.
  std::vector<double> edge_cost(E, 0.0);
  for (int e = 0; e < E; ++e)
    for (int k = 0; k < I.p; ++k)
      edge_cost[e] = std::max(edge_cost[e], I.omega.row(e).segment<3>(3 * k).norm());
  // Reliability of each dual edge: strongly distorted faces in an example have ill-defined
  // rotations, and their edges turn by up to pi; they count less (1/2 at reliability_angle).
  std::vector<double> edge_weight(E, 1.0);
  if (std::isfinite(options.reliability_angle)) {
    for (int e = 0; e < E; ++e) {
      const double x = edge_cost[e] / options.reliability_angle;
      edge_weight[e] = 1.0 / (1.0 + x * x);
    }
  }
  I.grad = std::make_unique<GradientOperator>(I.lrest, I.lfaces, options.area_weights);
  // Rotation components: faces linked by dual edges or rotational pairs (when the pairs'
  // rotations are given). Each needs a fixed face, a penalty face or a prescribed rotation to
  // pin its global rotation.
  auto rotation_solvers = [&](bool with_pairs) {
    Impl::RotationSolvers out;
    int rcount = 0;
    std::vector<int> rcomp;
    {
      DisjointSets sets(lm);
      for (Eigen::Index e = 0; e < I.ldual.rows(); ++e) sets.unite(I.ldual(e, 0), I.ldual(e, 1));
      if (with_pairs) {
        for (const auto& lp : I.lpairs) sets.unite(lp[0], lp[1]);
      }
      rcomp.resize(lm);
      std::vector<int> label(lm, -1);
      for (int f = 0; f < lm; ++f) {
        const int root = sets.find(f);
        if (label[root] < 0) label[root] = rcount++;
        rcomp[f] = label[root];
      }
    }
    out.components = rcount;
    // Its root face: the one nearest the frame face if that is in it, else nearest the rest
    // centroid of the parts it touches (choices by geometry, not by the numbering).
    std::vector<int> rroot(rcount, -1);
    {
      std::vector<std::vector<int>> touches(rcount), rfaces(rcount);  // its parts, its faces
      for (int f = 0; f < lm; ++f) {
        touches[rcomp[f]].push_back(I.lface_part[f]);
        rfaces[rcomp[f]].push_back(f);
      }
      for (std::vector<int>& t : touches) {
        std::sort(t.begin(), t.end());
        t.erase(std::unique(t.begin(), t.end()), t.end());
      }
      int frame_comp = -1;
      const Vec3 frame_point =
          I.frame < 0 ? Vec3::Zero()
                      : centroid(vertices, faces(I.frame, 0), faces(I.frame, 1), faces(I.frame, 2));
      if (I.frame >= 0) {
        const int lf =
            I.multires ? nearest_face(I.lrest, I.lfaces, frame_point, lpart_faces[fpart[I.frame]])
            : I.whole  ? I.frame
                       : lface_of[I.frame];
        frame_comp = rcomp[lf];
      }
      for (int k = 0; k < rcount; ++k) {
        Vec3 point = frame_point;
        if (k != frame_comp) {
          std::vector<int> ids;
          for (int c : touches[k])
            ids.insert(ids.end(), part_members[c].begin(), part_members[c].end());
          point = canonical_mean(vertices, ids);
        }
        rroot[k] = nearest_face(I.lrest, I.lfaces, point, rfaces[k]);
      }
    }
    std::vector<char> rfrozen(rcount, 0), rheld(rcount, 0);
    for (int f : I.lfixed_faces) rfrozen[rcomp[f]] = 1;
    for (int f : I.lhandle_faces) rheld[rcomp[f]] = 1;
    // Tree roots: the fixed faces, then the root of every rotation component without one.
    auto tree_roots = [&](const std::vector<int>& fixed) {
      std::vector<int> roots = fixed;
      std::vector<char> has(rcount, 0);
      for (int f : fixed) has[rcomp[f]] = 1;
      for (int k = 0; k < rcount; ++k) {
        if (!has[k]) roots.push_back(rroot[k]);
      }
      return roots;
    };
    const std::vector<std::array<int, 2>> no_pairs;
    const auto& pairs = with_pairs ? I.lpairs : no_pairs;
    // The natural shape is solved with the frozen faces fixed, or else the root face.
    std::vector<int> fixed_a = I.lfixed_faces;
    for (int k = 0; k < rcount; ++k) {
      if (!rfrozen[k]) fixed_a.push_back(rroot[k]);
    }
    out.a = std::make_unique<RotationSolver>(lm, I.ldual, pairs, options.joint_weight, fixed_a,
                                             tree_roots(fixed_a), std::vector<int>{}, 0.0,
                                             edge_cost, edge_weight);
    out.follow.assign(lm, 1);
    if (!I.lhandle_faces.empty()) {
      // A rotation component without frozen or handle faces follows its part's fitted
      // rotation; in this solve its root is held (only to keep the matrix definite).
      std::vector<int> fixed_b = I.lfixed_faces;
      for (int k = 0; k < rcount; ++k) {
        if (!rfrozen[k] && !rheld[k]) fixed_b.push_back(rroot[k]);
      }
      for (int f = 0; f < lm; ++f) out.follow[f] = !rfrozen[rcomp[f]] && !rheld[rcomp[f]];
      out.b = std::make_unique<RotationSolver>(lm, I.ldual, pairs, options.joint_weight, fixed_b,
                                               tree_roots(fixed_b), I.lhandle_faces,
                                               options.rotation_weight, edge_cost, edge_weight);
    }
    return out;
  };
  I.rot = rotation_solvers(true);
  // Without the pairs' rotations (deform(rotations=None)) the joints are free: a pair joining
  // two components must not join their gauges, or one of them would have no root and its
  // rotation would depend on the iteration (on the numbering). Those get their own solvers.
  if (!I.lpairs.empty()) {
    Impl::RotationSolvers split = rotation_solvers(false);
    if (split.components != I.rot.components) I.rot_free = std::move(split);
  }
  // Position penalty relative to the mean diagonal of the gradient term; with
  // multiresolution, dense rows are scaled by coarse/dense vertex counts so the balance
  // matches a single-resolution solve.
  I.lambda_pos = options.position_weight * I.grad->mean_diagonal *
                 (I.multires ? static_cast<double>(ln) / active_vertices : 1.0);
  for (int v : I.handle_all) I.handle_rows.push_back(I.make_row(v));
  if (I.frame >= 0) {
    for (int l = 0; l < 3; ++l) I.frame_rows.push_back(I.make_row(I.frame_vertices[l]));
  }
  I.lvpart = lvpart;
  I.pos_a = std::make_unique<PositionSolver>(I.lrest, I.lfaces, *I.grad, I.lfixed_vertices,
                                             std::vector<PositionSolver::Row>{}, 0.0, I.lvpart);
  I.pos_b = std::make_unique<PositionSolver>(I.lrest, I.lfaces, *I.grad, I.lfixed_vertices,
                                             I.handle_rows, I.lambda_pos, I.lvpart);
}

PoseSpaceDeformer::~PoseSpaceDeformer() = default;

Vertices PoseSpaceDeformer::Impl::run(const std::vector<Vertices>& hp,
                                      const Matrix3Array* rotations,
                                      const Eigen::Matrix4d* frame_transform,
                                      const Vectors3* rotation_vectors) const {
  const ParkWorkersOnExit park;
  stats = PoseSpaceStats();
  auto t0 = Clock::now();
  const Vertices targets = concat_targets(hp);
  const Eigen::VectorXd w = weights(targets, rotations, frame_transform);
  stats.ms_weights = ms_since(t0);
  if (!w.allFinite()) fail(kOverflow);
  if (lfaces.rows() == 0) {  // no part has a control: everything stays at rest
    last_weights = w;
    return rest;
  }

  t0 = Clock::now();
  Matrix3Array Q, S;
  blend(w, &Q, &S);
  stats.ms_blend = ms_since(t0);
  const Matrix3Array* G = rotations && r > 0 ? rotations : nullptr;
  const RotationSolvers& rs = !G && rot_free.a ? rot_free : rot;
  const RotationSolver* rot_a = rs.a.get();
  const RotationSolver* rot_b = rs.b.get();
  const int lm = static_cast<int>(lfaces.rows());

  // Step 1 and 2 without handles: the natural blended shape, up to a rigid motion.
  t0 = Clock::now();
  Matrix3Array R0;
  // Turns past half a turn: the geodesic energy from the start, residuals on the vectors'
  // branches (joints here; the handles in the solve with the handle rotations below).
  std::vector<Vec3> pair_turns;
  if (rotation_vectors) {
    for (int q = 0; q < r; ++q) pair_turns.push_back(rotation_vectors->row(h + q).transpose());
    stats.iterations_first =
        rot_a->solve_log(Q, G, Matrix3Array(), nullptr,
                         rot_b ? opt.gauge_steps : opt.rotation_iterations, &R0, &pair_turns);
  } else {
    stats.iterations_first =
        solve_rotations(*rot_a, Q, G, Matrix3Array(), nullptr, rot_b == nullptr, &R0);
  }
  stats.ms_rotations += ms_since(t0);
  t0 = Clock::now();
  Matrix3Array T(lm);
  for (int i = 0; i < lm; ++i) T[i] = R0[i] * S[i];
  Vertices y0;
  pos_a->solve(T, nullptr, &y0);
  stats.ms_positions += ms_since(t0);

  // Fit the natural shape to the handles: one rotation per part (none for a part with frozen
  // faces: they hold it in place), one per handle for its faces.
  t0 = Clock::now();
  Matrix3Array Rv0;
  if (multires) vertex_rotations(R0, &Rv0);
  std::vector<int> cverts = handle_all;
  Vertices ctargets = targets;
  Vertices frame_targets;
  if (frame >= 0 && frame_transform) {
    // The frame face as the natural shape has it, turned and moved to frame_transform.
    Vertices xf(3, 3);
    for (int l = 0; l < 3; ++l) xf.row(l) = dense_position(frame_vertices[l], y0, Rv0, w);
    const Mat3 Rn = face_rotation(frame_rest_inverse, xf.row(0), xf.row(1), xf.row(2));
    const Mat3 Rf = frame_transform->topLeftCorner<3, 3>();
    const Vec3 o = Rf * frame_rest_centroid + frame_transform->topRightCorner<3, 1>();
    const Eigen::RowVector3d c = xf.colwise().mean();
    frame_targets.resize(3, 3);
    for (int l = 0; l < 3; ++l) {
      frame_targets.row(l) = (Rf * Rn.transpose() * (xf.row(l) - c).transpose() + o).transpose();
      cverts.push_back(frame_vertices[l]);
    }
    ctargets.conservativeResize(ctargets.rows() + 3, 3);
    ctargets.bottomRows(3) = frame_targets;
  }
  Vertices x0(static_cast<Eigen::Index>(cverts.size()), 3);
  for (size_t s = 0; s < cverts.size(); ++s) {
    x0.row(static_cast<Eigen::Index>(s)) = dense_position(cverts[s], y0, Rv0, w).transpose();
  }
  std::vector<Mat3> Gpart(parts, Mat3::Identity());
  {
    std::vector<std::vector<int>> rows(parts);
    for (size_t s = 0; s < cverts.size(); ++s)
      rows[vpart[cverts[s]]].push_back(static_cast<int>(s));
    for (int c = 0; c < parts; ++c) {
      if (part_frozen[c] || rows[c].empty()) continue;
      Gpart[c] = best_rotation(gather_rows(x0, rows[c]), gather_rows(ctargets, rows[c]));
    }
  }
  stats.ms_fit = ms_since(t0);

  t0 = Clock::now();
  Matrix3Array R(lm);
  if (rot_b) {
    Matrix3Array Z(lm, Mat3::Identity()), init(lm);
    std::vector<Mat3> Gj(h);
    for (int j = 0; j < h; ++j) {
      Gj[j] = Gpart[vpart[handle_all[handle_offset[j]]]];
      const int b = handle_offset[j], e = handle_offset[j + 1];
      if (e - b < 3) continue;
      const Vertices xs = x0.middleRows(b, e - b), ts = targets.middleRows(b, e - b);
      if (planarity(xs) > 1e-6 && planarity(ts) > 1e-6) Gj[j] = best_rotation(xs, ts);
    }
    for (int i = 0; i < lm; ++i) init[i] = Gpart[lface_part[i]] * R0[i];
    for (size_t s = 0; s < lhandle_faces.size(); ++s) {
      const int f = lhandle_faces[s];
      Z[f] = Gj[lhandle_owner[s]] * R0[f];
    }
    if (rotation_vectors) {
      // From the natural shape a face of handle j is off its target by G_j exactly; its log
      // with the handle's turns: the branch nearest the handle's vector less the natural
      // shape's own turn of the handle (principal: the examples' blend turns a handle by less
      // than half a turn).
      std::vector<Vec3> turn(h);
      for (int j = 0; j < h; ++j) {
        const int b = handle_offset[j], e = handle_offset[j + 1];
        const Vec3 natural =
            rotation_log(best_rotation(handle_rest.middleRows(b, e - b), x0.middleRows(b, e - b)));
        turn[j] = rotation_log_near(Gj[j], rotation_vectors->row(j).transpose() - natural);
      }
      // The start: the natural shape turned, per part, by the rotation G_j of its first handle
      // with faces (the rigid fit of all handle vertices, today's start, is undefined at half a
      // turn; the natural shape itself, whose root face is held at rest, leaves every handle
      // off by a common tilt, which slowed the steps and let a twist past a whole turn drift).
      // The steps begin from the handles' differences: the first spreads them (and their turns)
      // over the faces between the handles, as the material-aware blend spreads an anchor's
      // turn, and the others correct.
      std::vector<int> ref(parts, -1);
      for (const int j : lhandle_owner) {
        const int c = vpart[handle_all[handle_offset[j]]];
        if (!part_frozen[c] && (ref[c] < 0 || j < ref[c])) ref[c] = j;
      }
      Matrix3Array start(lm);
      for (int i = 0; i < lm; ++i) {
        const int c = lface_part[i];
        start[i] = ref[c] < 0 ? R0[i] : Mat3(Gj[ref[c]] * R0[i]);
      }
      std::vector<Vec3> face_turns(lm, Vec3::Zero());
      for (size_t s = 0; s < lhandle_faces.size(); ++s) {
        const int j = lhandle_owner[s], c = vpart[handle_all[handle_offset[j]]];
        face_turns[lhandle_faces[s]] = ref[c] < 0 ? turn[j] : Vec3(turn[j] - turn[ref[c]]);
      }
      stats.iterations_second =
          rot_b->solve_log(Q, G, Z, &start, opt.rotation_iterations, &R, nullptr, &face_turns);
    } else {
      stats.iterations_second = solve_rotations(*rot_b, Q, G, Z, &init, true, &R);
    }
  }
  for (int i = 0; i < lm; ++i) {
    if (rs.follow[i]) R[i] = Gpart[lface_part[i]] * R0[i];
  }
  stats.ms_rotations += ms_since(t0);

  t0 = Clock::now();
  for (int i = 0; i < lm; ++i) T[i] = R[i] * S[i];
  Matrix3Array Rv;
  if (multires) vertex_rotations(R, &Rv);
  const bool with_frame = frame >= 0 && frame_transform;
  const size_t nrows = handle_rows.size() + (with_frame ? 3 : 0);
  Vertices row_t(static_cast<Eigen::Index>(nrows), 3);
  for (size_t s = 0; s < handle_all.size(); ++s) {
    row_t.row(static_cast<Eigen::Index>(s)) =
        row_target(handle_all[s], targets.row(static_cast<Eigen::Index>(s)).transpose(), Rv, w)
            .transpose();
  }
  if (with_frame) {
    for (int l = 0; l < 3; ++l) {
      row_t.row(static_cast<Eigen::Index>(handle_all.size()) + l) =
          row_target(frame_vertices[l], frame_targets.row(l).transpose(), Rv, w).transpose();
    }
    if (!pos_b_frame) {
      std::vector<PositionSolver::Row> rows = handle_rows;
      rows.insert(rows.end(), frame_rows.begin(), frame_rows.end());
      pos_b_frame = std::make_unique<PositionSolver>(lrest, lfaces, *grad, lfixed_vertices, rows,
                                                     lambda_pos, lvpart);
    }
  }
  Vertices y;
  (with_frame ? pos_b_frame : pos_b)->solve(T, nrows ? &row_t : nullptr, &y);
  stats.ms_positions += ms_since(t0);

  if (whole) {
    if (!y.allFinite()) fail(kOverflow);
    last_weights = w;
    return y;
  }
  if (!multires) {
    Vertices X = rest;
    for (Eigen::Index c = 0; c < y.rows(); ++c) X.row(lvertices[c]) = y.row(c);
    if (!X.allFinite()) fail(kOverflow);
    last_weights = w;
    return X;
  }

  t0 = Clock::now();
  Vertices X(n, 3);
  auto body = [&](int b, int e) {
    for (int v = b; v < e; ++v) {
      if (at_rest[v]) {
        X.row(v) = rest.row(v);
      } else {
        X.row(v) = dense_position(v, y, Rv, w).transpose();
      }
    }
  };
  if (n < kParallelMin) {
    body(0, n);
  } else {
    parallel_ranges(n, kParallelMin / 2, kTasks, body);
  }
  stats.ms_transfer = ms_since(t0);
  if (!X.allFinite()) fail(kOverflow);
  last_weights = w;
  return X;
}

Vertices PoseSpaceDeformer::deform(const std::vector<Vertices>& handle_positions,
                                   const Matrix3Array* rotations,
                                   const Eigen::Matrix4d* frame_transform,
                                   const Vectors3* rotation_vectors) const {
  impl_->check_inputs(handle_positions, rotations, frame_transform, rotation_vectors);
  const std::lock_guard<std::mutex> lock(impl_->busy);
  const PoseSpaceStats kept = impl_->stats;
  try {
    return impl_->run(handle_positions, rotations, frame_transform, rotation_vectors);
  } catch (...) {
    impl_->stats = kept;  // a refused call changes nothing
    throw;
  }
}

Eigen::VectorXd PoseSpaceDeformer::pose_weights(const std::vector<Vertices>& handle_positions,
                                                const Matrix3Array* rotations,
                                                const Eigen::Matrix4d* frame_transform) const {
  impl_->check_inputs(handle_positions, rotations, frame_transform);
  Eigen::VectorXd w =
      impl_->weights(impl_->concat_targets(handle_positions), rotations, frame_transform);
  if (!w.allFinite()) fail(kOverflow);
  return w;
}

Eigen::VectorXd PoseSpaceDeformer::example_weights() const {
  const std::lock_guard<std::mutex> lock(impl_->busy);
  return impl_->last_weights;
}
PoseSpaceStats PoseSpaceDeformer::last_stats() const {
  const std::lock_guard<std::mutex> lock(impl_->busy);
  return impl_->stats;
}
int PoseSpaceDeformer::num_examples() const { return impl_->p; }
int PoseSpaceDeformer::num_handles() const { return impl_->h; }
int PoseSpaceDeformer::num_rotational() const { return impl_->r; }
bool PoseSpaceDeformer::multiresolution() const { return impl_->multires; }
const Faces& PoseSpaceDeformer::solve_faces() const { return impl_->lfaces; }
const std::vector<int>& PoseSpaceDeformer::solve_vertices() const { return impl_->lvertices; }

}  // namespace matdeform
