#include "matdeform/deformer.hpp"

#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>
#include <string>

#include "matdeform/mesh.hpp"
#include "matdeform/reposition.hpp"
#include "matdeform/stiffness.hpp"
#include "matdeform/transforms.hpp"
#include "matdeform/weights.hpp"
#include "task_pool.hpp"

namespace matdeform {

namespace {
std::vector<int> sorted_unique(std::vector<int> v) {
  std::sort(v.begin(), v.end());
  v.erase(std::unique(v.begin(), v.end()), v.end());
  return v;
}

// The caller's branch of each anchor's rotation log (Eq. 2 blends them as given), after checking
// that each is a log of that anchor's rotation factor, i.e. exp(v_a) = R_a.
void use_rotation_vectors(const Vectors3& v, std::vector<TransformLog>* logs) {
  const size_t k = logs->size();
  if (static_cast<size_t>(v.rows()) != k) {
    throw std::invalid_argument("rotation_vectors: expected shape (" + std::to_string(k) +
                                ",3), one per anchor, got " + std::to_string(v.rows()) + " rows");
  }
  for (size_t a = 0; a < k; ++a) {
    check_rotation_vector(v.row(static_cast<Eigen::Index>(a)).transpose(),
                          rotation_exp((*logs)[a].rotation),
                          "rotation_vectors[" + std::to_string(a) + "]",
                          "the rotation of transforms[" + std::to_string(a) + "]");
  }
  for (size_t a = 0; a < k; ++a) (*logs)[a].rotation = v.row(static_cast<Eigen::Index>(a));
}
}  // namespace

MaterialDeformer::MaterialDeformer(const Vertices& vertices, const Faces& faces,
                                   const AnchorList& anchors, const Eigen::VectorXd& shear,
                                   const RowMatrix& bend, const DeformerOptions& options)
    : rest_(vertices), axes_(options.axes) {
  validate_mesh(vertices, faces);
  const int n = static_cast<int>(vertices.rows());
  const int m = static_cast<int>(faces.rows());
  if (shear.size() != m) throw std::invalid_argument("shear: expected one value per face");
  check_stiffness(shear.data(), shear.size(), "shear");
  const DualEdges dual = dual_edges(faces);
  if (bend.rows() != dual.pairs.rows() || (bend.cols() != 1 && bend.cols() != 3)) {
    throw std::invalid_argument("bend: expected shape (E,1) or (E,3) with E dual edges");
  }
  check_stiffness(bend.data(), bend.size(), "bend");
  validate_anchors(m, anchors);
  if (!(axes_.transpose() * axes_).isIdentity(1e-9) || axes_.determinant() < 0) {
    throw std::invalid_argument("axes: expected a rotation matrix (orthonormal columns)");
  }

  // Region of interest: compact to the region's faces and vertices (whole mesh by default).
  std::vector<int> face_map(m, -1);
  if (options.region) {
    sub_face_ids_ = sorted_unique(*options.region);
    if (sub_face_ids_.empty()) throw std::invalid_argument("region: expected at least one face");
    if (sub_face_ids_.front() < 0 || sub_face_ids_.back() >= m) {
      throw std::invalid_argument("region: face index out of range");
    }
  } else {
    sub_face_ids_.resize(m);
    for (int f = 0; f < m; ++f) sub_face_ids_[f] = f;
  }
  const int ms = static_cast<int>(sub_face_ids_.size());
  for (int s = 0; s < ms; ++s) face_map[sub_face_ids_[s]] = s;
  std::vector<int> vmap(n, -1);
  // Without a region every vertex takes part (loose ones keep rest or pinned positions).
  if (!options.region) std::fill(vmap.begin(), vmap.end(), 0);
  for (int f : sub_face_ids_)
    for (int l = 0; l < 3; ++l) vmap[faces(f, l)] = 0;
  for (int v = 0; v < n; ++v) {
    if (vmap[v] == 0) {
      vmap[v] = static_cast<int>(sub_vertices_.size());
      sub_vertices_.push_back(v);
    }
  }
  sub_rest_.resize(static_cast<Eigen::Index>(sub_vertices_.size()), 3);
  for (size_t s = 0; s < sub_vertices_.size(); ++s) {
    sub_rest_.row(static_cast<Eigen::Index>(s)) = vertices.row(sub_vertices_[s]);
  }
  sub_faces_.resize(ms, 3);
  shear_.resize(ms);
  for (int s = 0; s < ms; ++s) {
    for (int l = 0; l < 3; ++l) sub_faces_(s, l) = vmap[faces(sub_face_ids_[s], l)];
    shear_(s) = shear(sub_face_ids_[s]);
  }
  if (options.region) {
    std::vector<char> outside_use(n, 0);
    for (int f = 0; f < m; ++f) {
      if (face_map[f] < 0)
        for (int l = 0; l < 3; ++l) outside_use[faces(f, l)] = 1;
    }
    for (size_t s = 0; s < sub_vertices_.size(); ++s) {
      if (outside_use[sub_vertices_[s]]) boundary_.push_back(static_cast<int>(s));
    }
  }
  for (size_t a = 0; a < anchors.size(); ++a) {
    std::vector<int> sub;
    for (int f : anchors[a]) {
      if (face_map[f] < 0) {
        throw std::invalid_argument("anchors[" + std::to_string(a) + "]: face " +
                                    std::to_string(f) + " is outside the region");
      }
      sub.push_back(face_map[f]);
    }
    anchors_.push_back(std::move(sub));
  }
  if (options.pinned) {
    std::vector<int> p;
    std::vector<char> seen(n, 0);
    for (int v : *options.pinned) {
      if (v < 0 || v >= n) throw std::invalid_argument("pinned: vertex index out of range");
      if (seen[v]) throw std::invalid_argument("pinned: indices must be unique");
      seen[v] = 1;
      if (vmap[v] < 0) {
        throw std::invalid_argument("pinned: vertex " + std::to_string(v) +
                                    " is not part of the region");
      }
      if (std::binary_search(boundary_.begin(), boundary_.end(), vmap[v])) {
        throw std::invalid_argument("pinned: vertex " + std::to_string(v) +
                                    " lies on the region boundary, which stays at rest");
      }
      p.push_back(vmap[v]);
    }
    pinned_ = std::move(p);
  }

  // Dual edges inside the region keep their relative order under the monotone face map.
  std::vector<Eigen::Index> rows;
  for (Eigen::Index e = 0; e < dual.pairs.rows(); ++e) {
    if (face_map[dual.pairs(e, 0)] >= 0 && face_map[dual.pairs(e, 1)] >= 0) rows.push_back(e);
  }
  IndexPairs sub_pairs(static_cast<Eigen::Index>(rows.size()), 2);
  for (size_t r = 0; r < rows.size(); ++r) {
    sub_pairs(static_cast<Eigen::Index>(r), 0) = face_map[dual.pairs(rows[r], 0)];
    sub_pairs(static_cast<Eigen::Index>(r), 1) = face_map[dual.pairs(rows[r], 1)];
  }
  for (Eigen::Index c = 0; c < bend.cols(); ++c) {
    Eigen::VectorXd phi(static_cast<Eigen::Index>(rows.size()));
    for (size_t r = 0; r < rows.size(); ++r) phi(static_cast<Eigen::Index>(r)) = bend(rows[r], c);
    axis_weights_.push_back(harmonic_weights(ms, sub_pairs, phi, anchors_));
  }
  mean_weights_ = axis_weights_[0];
  if (axis_weights_.size() == 3) {
    mean_weights_ = (axis_weights_[0] + axis_weights_[1] + axis_weights_[2]) / 3.0;
  }
  weights_full_ = RowMatrix::Zero(m, static_cast<Eigen::Index>(anchors.size()));
  for (int s = 0; s < ms; ++s) weights_full_.row(sub_face_ids_[s]) = mean_weights_.row(s);

  // Region vertex -> anchors that use it, for anchors following their full transform.
  std::vector<std::pair<int, int>> va;
  for (size_t a = 0; a < anchors_.size(); ++a) {
    for (int f : anchors_[a]) {
      for (int l = 0; l < 3; ++l) va.emplace_back(sub_faces_(f, l), static_cast<int>(a));
    }
  }
  std::sort(va.begin(), va.end());
  va.erase(std::unique(va.begin(), va.end()), va.end());
  for (size_t s = 0; s < va.size(); ++s) {
    if (anchor_vertices_.empty() || anchor_vertices_.back() != va[s].first) {
      anchor_vertices_.push_back(va[s].first);
      av_offsets_.push_back(static_cast<int>(s));
    }
    av_anchors_.push_back(va[s].second);
  }
  av_offsets_.push_back(static_cast<int>(va.size()));

  // Parts (vertices joined by region faces) with no anchor face and no pinned vertex stay at
  // rest bit for bit: fixed there rather than solved to rest up to round-off.
  {
    const int ns = static_cast<int>(sub_vertices_.size());
    DisjointSets parts(ns);
    for (int f = 0; f < ms; ++f) {
      parts.unite(sub_faces_(f, 0), sub_faces_(f, 1));
      parts.unite(sub_faces_(f, 0), sub_faces_(f, 2));
    }
    std::vector<char> controlled(ns, 0);
    for (int v : anchor_vertices_) controlled[parts.find(v)] = 1;
    if (pinned_)
      for (int v : *pinned_) controlled[parts.find(v)] = 1;
    for (int v = 0; v < ns; ++v) {
      if (!controlled[parts.find(v)] && !std::binary_search(boundary_.begin(), boundary_.end(), v))
        still_.push_back(v);
    }
  }
  follow_ = std::make_unique<PoissonRepositioner>(sub_rest_, sub_faces_, shear_,
                                                  fixed_set(pinned_ ? *pinned_ : anchor_vertices_));
  for (int v : follow_->fixed()) {
    std::pair<int, int> range{0, 0};
    const auto it = std::lower_bound(anchor_vertices_.begin(), anchor_vertices_.end(), v);
    if (!std::binary_search(boundary_.begin(), boundary_.end(), v) &&
        it != anchor_vertices_.end() && *it == v) {
      const size_t j = static_cast<size_t>(it - anchor_vertices_.begin());
      range = {av_offsets_[j], av_offsets_[j + 1]};
    }
    follow_anchors_.push_back(range);
  }
}

MaterialDeformer::~MaterialDeformer() = default;

std::vector<int> MaterialDeformer::fixed_set(const std::vector<int>& primary) const {
  // Primary vertices first (in the caller's order), then region boundary vertices and parts
  // without control, at rest. A boundary vertex is never also primary: the region edge must
  // stay attached to the rest.
  std::vector<int> out;
  for (int v : primary) {
    if (!std::binary_search(boundary_.begin(), boundary_.end(), v)) out.push_back(v);
  }
  out.insert(out.end(), boundary_.begin(), boundary_.end());
  out.insert(out.end(), still_.begin(), still_.end());
  return out;
}

const PoissonRepositioner& MaterialDeformer::repositioner(bool follow) const {
  if (follow || pinned_) return *follow_;
  if (!free_) {
    free_ = std::make_unique<PoissonRepositioner>(sub_rest_, sub_faces_, shear_, fixed_set({}));
  }
  return *free_;
}

RowMatrix MaterialDeformer::axis_weights(int axis) const {
  if (axis < 0 || axis > 2) throw std::invalid_argument("axis must be 0, 1 or 2");
  const RowMatrix& w = axis_weights_[anisotropic() ? static_cast<size_t>(axis) : 0];
  RowMatrix out = RowMatrix::Zero(weights_full_.rows(), weights_full_.cols());
  for (size_t s = 0; s < sub_face_ids_.size(); ++s) {
    out.row(sub_face_ids_[s]) = w.row(static_cast<Eigen::Index>(s));
  }
  return out;
}

int MaterialDeformer::substitution_threads() const {
  const std::lock_guard<std::mutex> lock(mutex_);
  return last_substitution_threads_;
}

Matrix3Array MaterialDeformer::face_transforms() const {
  const std::lock_guard<std::mutex> lock(mutex_);
  Matrix3Array out(static_cast<size_t>(weights_full_.rows()), Eigen::Matrix3d::Identity());
  if (last_logs_.empty()) return out;
  Matrix3Array blended;
  if (anisotropic()) {
    blend_all_anisotropic(last_logs_, axis_weights_[0], axis_weights_[1], axis_weights_[2], axes_,
                          &blended);
  } else {
    blend_all(last_logs_, axis_weights_[0], &blended);
  }
  for (size_t s = 0; s < sub_face_ids_.size(); ++s) out[sub_face_ids_[s]] = blended[s];
  return out;
}

void MaterialDeformer::solve_region(const std::vector<Eigen::Matrix4d>& transforms,
                                    bool has_translation, const Vertices* pinned_positions,
                                    const Vectors3* rotation_vectors, Vertices* sub_out) const {
  const size_t k = anchors_.size();
  if (transforms.size() != k) {
    throw std::invalid_argument("transforms: expected " + std::to_string(k) + " transforms, got " +
                                std::to_string(transforms.size()));
  }
  std::vector<TransformLog> logs(k);
  for (size_t a = 0; a < k; ++a) {
    try {
      logs[a] = transform_log(transforms[a].topLeftCorner<3, 3>());
    } catch (const std::invalid_argument& e) {
      throw std::invalid_argument("transforms[" + std::to_string(a) + "]: " + e.what());
    }
    if (has_translation && !transforms[a].topRightCorner<3, 1>().allFinite()) {
      throw std::invalid_argument("transforms[" + std::to_string(a) +
                                  "] has a non-finite translation");
    }
  }
  if (rotation_vectors) use_rotation_vectors(*rotation_vectors, &logs);
  const PoissonRepositioner& rep = repositioner(has_translation);
  const std::vector<int>& fixed = rep.fixed();
  Vertices fixed_pos(static_cast<Eigen::Index>(fixed.size()), 3);
  size_t s0 = 0;
  if (pinned_positions) {
    if (!pinned_) throw std::invalid_argument("pinned_positions given but no vertices are pinned");
    if (pinned_positions->rows() != static_cast<Eigen::Index>(pinned_->size())) {
      throw std::invalid_argument("pinned_positions: one row per pinned vertex expected");
    }
    if (!pinned_positions->allFinite()) {
      throw std::invalid_argument("pinned_positions: contains NaN or infinity");
    }
    fixed_pos.topRows(pinned_positions->rows()) = *pinned_positions;
    s0 = pinned_->size();
  }
  // Anchor vertices follow the mean of their anchors' full transforms; others stay at rest.
  // Only follow_ fixes anchor vertices, and only 4x4 transforms carry a translation to follow.
  const bool follow = has_translation && &rep == follow_.get();
  for (size_t s = s0; s < fixed.size(); ++s) {
    const Eigen::Vector3d x = sub_rest_.row(fixed[s]).transpose();
    Eigen::Vector3d p = x;
    const int b = follow ? follow_anchors_[s].first : 0;
    const int e = follow ? follow_anchors_[s].second : 0;
    if (e > b) {
      p.setZero();
      for (int t = b; t < e; ++t) {
        const Eigen::Matrix4d& T = transforms[static_cast<size_t>(av_anchors_[t])];
        p += T.topLeftCorner<3, 3>() * x + T.topRightCorner<3, 1>();
      }
      p /= static_cast<double>(e - b);
    }
    fixed_pos.row(static_cast<Eigen::Index>(s)) = p.transpose();
  }
  // Blend (Eq. 2) block by block inside the solve, where each block is consumed right away.
  rep.solve(
      [&](int gb, int ge, double* T) {
        if (anisotropic()) {
          blend_groups_anisotropic(logs, axis_weights_[0], axis_weights_[1], axis_weights_[2],
                                   axes_, gb, ge, T);
        } else {
          blend_groups(logs, axis_weights_[0], gb, ge, T);
        }
      },
      fixed_pos, sub_out);
  last_logs_ = logs;
  last_substitution_threads_ = rep.substitution_threads();
}

Vertices MaterialDeformer::deform(const std::vector<Eigen::Matrix4d>& transforms,
                                  bool has_translation, const Vertices* pinned_positions,
                                  const Vectors3* rotation_vectors) const {
  const std::lock_guard<std::mutex> lock(mutex_);
  const ParkWorkersOnExit park;  // the solve's helper threads sleep as soon as it is done
  Vertices sub_out;
  solve_region(transforms, has_translation, pinned_positions, rotation_vectors, &sub_out);
  if (sub_vertices_.size() == static_cast<size_t>(rest_.rows())) return sub_out;
  Vertices out = rest_;
  for (size_t s = 0; s < sub_vertices_.size(); ++s) {
    out.row(sub_vertices_[s]) = sub_out.row(static_cast<Eigen::Index>(s));
  }
  return out;
}

void MaterialDeformer::deform(const std::vector<Eigen::Matrix4d>& transforms, bool has_translation,
                              const Vertices* pinned_positions, float* out,
                              const Vectors3* rotation_vectors) const {
  const std::lock_guard<std::mutex> lock(mutex_);
  const ParkWorkersOnExit park;
  solve_region(transforms, has_translation, pinned_positions, rotation_vectors, &work_out_);
  const int n = static_cast<int>(rest_.rows());
  const bool whole = sub_vertices_.size() == static_cast<size_t>(n);
  // Rounded on the solve's threads: the caller's next step (a float32 key) reads it at once.
  parallel_ranges(n, 8192, 8, [&](int b, int e) {
    const Vertices& src = whole ? work_out_ : rest_;
    for (int v = b; v < e; ++v)
      for (int c = 0; c < 3; ++c)
        out[3 * static_cast<size_t>(v) + c] = static_cast<float>(src(v, c));
  });
  if (whole) return;
  for (size_t s = 0; s < sub_vertices_.size(); ++s) {
    for (int c = 0; c < 3; ++c) {
      out[3 * static_cast<size_t>(sub_vertices_[s]) + c] =
          static_cast<float>(work_out_(static_cast<Eigen::Index>(s), c));
    }
  }
}

}  // namespace matdeform
