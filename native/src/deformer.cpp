#include "matdeform/deformer.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "matdeform/mesh.hpp"
#include "matdeform/reposition.hpp"
#include "matdeform/transforms.hpp"
#include "matdeform/weights.hpp"

namespace matdeform {

namespace {
void check_positive(const Eigen::VectorXd& x, const char* name) {
  for (Eigen::Index i = 0; i < x.size(); ++i) {
    if (!std::isfinite(x(i)) || !(x(i) > 0.0)) {
      throw std::invalid_argument(std::string(name) + "[" + std::to_string(i) +
                                  "] must be finite and > 0");
    }
  }
}
}  // namespace

MaterialDeformer::MaterialDeformer(const Vertices& vertices, const Faces& faces,
                                   const AnchorList& anchors, const Eigen::VectorXd& shear,
                                   const Eigen::VectorXd& bend,
                                   std::optional<std::vector<int>> pinned)
    : rest_(vertices), faces_(faces), anchors_(anchors), shear_(shear), pinned_(std::move(pinned)) {
  validate_mesh(vertices, faces);
  const int m = static_cast<int>(faces.rows());
  if (shear.size() != m) throw std::invalid_argument("shear: expected one value per face");
  check_positive(shear, "shear");
  check_positive(bend, "bend");
  const DualEdges dual = dual_edges(faces);
  if (bend.size() != dual.pairs.rows()) {
    throw std::invalid_argument("bend: expected one value per dual edge");
  }
  validate_anchors(m, anchors);
  weights_ = harmonic_weights(m, dual.pairs, bend, anchors);

  // Vertex -> anchors that use it, for anchors whose vertices follow their full transform.
  std::vector<std::pair<int, int>> va;
  for (size_t a = 0; a < anchors.size(); ++a) {
    for (int f : anchors[a]) {
      for (int l = 0; l < 3; ++l) va.emplace_back(faces(f, l), static_cast<int>(a));
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

  follow_ = std::make_unique<PoissonRepositioner>(vertices, faces, shear,
                                                  pinned_ ? *pinned_ : anchor_vertices_);
}

MaterialDeformer::~MaterialDeformer() = default;

const PoissonRepositioner& MaterialDeformer::repositioner(bool follow) const {
  if (follow || pinned_) return *follow_;
  if (!free_)
    free_ = std::make_unique<PoissonRepositioner>(rest_, faces_, shear_, std::vector<int>{});
  return *free_;
}

Vertices MaterialDeformer::deform(const std::vector<Eigen::Matrix4d>& transforms,
                                  bool has_translation, const Vertices* pinned_positions) const {
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
  blend_all(logs, weights_, &blended_);

  const PoissonRepositioner& rep = repositioner(has_translation);
  const std::vector<int>& fixed = rep.fixed();
  Vertices fixed_pos(static_cast<Eigen::Index>(fixed.size()), 3);
  if (pinned_positions) {
    if (!pinned_) throw std::invalid_argument("pinned_positions given but no vertices are pinned");
    fixed_pos = *pinned_positions;
  } else {
    // Anchor vertices follow the mean of their anchors' full transforms; others stay at rest.
    for (size_t s = 0; s < fixed.size(); ++s) {
      const int v = fixed[s];
      const Eigen::Vector3d x = rest_.row(v).transpose();
      Eigen::Vector3d p = x;
      auto it = std::lower_bound(anchor_vertices_.begin(), anchor_vertices_.end(), v);
      if (has_translation && it != anchor_vertices_.end() && *it == v) {
        const size_t j = static_cast<size_t>(it - anchor_vertices_.begin());
        p.setZero();
        const int b = av_offsets_[j], e = av_offsets_[j + 1];
        for (int t = b; t < e; ++t) {
          const Eigen::Matrix4d& T = transforms[static_cast<size_t>(av_anchors_[t])];
          p += T.topLeftCorner<3, 3>() * x + T.topRightCorner<3, 1>();
        }
        p /= static_cast<double>(e - b);
      }
      fixed_pos.row(static_cast<Eigen::Index>(s)) = p.transpose();
    }
  }
  Vertices out;
  rep.solve(blended_, fixed_pos, &out);
  return out;
}

}  // namespace matdeform
