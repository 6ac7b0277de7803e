// Binned SAH (Wald 2007) over primitive or instance boxes, 16 bins per axis, object-median
// fallback when the centroids coincide. Costs are evaluated in double so huge boxes
// (coordinates near FLT_MAX) still compare; infinite areas never win a split.
#include "nv_internal.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace clastrace::engine::nv {
namespace {

constexpr int kBins = 16;
constexpr double kInf = std::numeric_limits<double>::infinity();

double half_area(const Box& b) {
  if (!b.valid()) return 0.0;
  double dx = double(b.hi[0]) - b.lo[0], dy = double(b.hi[1]) - b.lo[1], dz = double(b.hi[2]) - b.lo[2];
  return dx * dy + dy * dz + dz * dx;
}

struct Builder {
  std::span<const Box> boxes;
  std::vector<float> centroid;  // 3 per item
  std::vector<uint32_t> items;
  std::vector<NvNode> nodes;

  void emit_leaf(uint32_t node, uint32_t begin, uint32_t end, const Box& bounds) {
    NvNode& n = nodes[node];
    for (int a = 0; a < 3; ++a) {
      n.bounds_min[a] = bounds.lo[a];
      n.bounds_max[a] = bounds.hi[a];
    }
    n.first = begin;
    n.count = end - begin;
  }

  // Builds the subtree of items [begin, end) at node index `node` (already allocated).
  void build(uint32_t node, uint32_t begin, uint32_t end, int depth) {
    Box bounds = Box::empty(), cbounds = Box::empty();
    for (uint32_t i = begin; i < end; ++i) {
      bounds.grow(boxes[items[i]]);
      cbounds.grow_point(&centroid[3 * size_t(items[i])]);
    }
    const uint32_t count = end - begin;
    if (count <= 1) return emit_leaf(node, begin, end, bounds);
    // Best binned split over the three axes, binned in one pass over the items.
    int best_axis = -1;
    int best_bin = 0;
    double best_cost = kInf;
    double lo[3], scale[3];
    bool usable[3];
    for (int a = 0; a < 3; ++a) {
      lo[a] = cbounds.lo[a];
      const double extent = double(cbounds.hi[a]) - lo[a];
      usable[a] = extent > 0.0 && std::isfinite(extent);
      scale[a] = usable[a] ? kBins / extent : 0.0;
    }
    // Bin of a centroid; NaN (inf - inf on an unusable axis) and infinities clamp
    // without a float-to-int conversion out of range.
    auto bin_of = [&](float c, int a) {
      const double x = (double(c) - lo[a]) * scale[a];
      if (!(x >= 1.0)) return 0;
      if (x >= double(kBins - 1)) return kBins - 1;
      return int(x);
    };
    Box bin_box[3][kBins];
    uint32_t bin_count[3][kBins] = {};
    for (auto& axis : bin_box)
      for (auto& b : axis) b = Box::empty();
    for (uint32_t i = begin; i < end; ++i) {
      const uint32_t it = items[i];
      const Box& box = boxes[it];
      for (int a = 0; a < 3; ++a) {
        const int k = bin_of(centroid[3 * size_t(it) + a], a);
        bin_box[a][k].grow(box);
        ++bin_count[a][k];
      }
    }
    for (int a = 0; a < 3; ++a) {
      if (!usable[a]) continue;
      double right_area[kBins];
      uint32_t right_count[kBins];
      Box acc = Box::empty();
      uint32_t n = 0;
      for (int k = kBins - 1; k > 0; --k) {
        acc.grow(bin_box[a][k]);
        n += bin_count[a][k];
        right_area[k] = half_area(acc);
        right_count[k] = n;
      }
      acc = Box::empty();
      n = 0;
      for (int k = 0; k < kBins - 1; ++k) {
        acc.grow(bin_box[a][k]);
        n += bin_count[a][k];
        if (n == 0 || right_count[k + 1] == 0) continue;
        const double cost = half_area(acc) * n + right_area[k + 1] * right_count[k + 1];
        if (cost < best_cost) {
          best_cost = cost;
          best_axis = a;
          best_bin = k;
        }
      }
    }
    const double leaf_cost = half_area(bounds) * count;
    if (count <= kNvMaxLeafSize && (best_axis < 0 || !(best_cost + half_area(bounds) < leaf_cost)))
      return emit_leaf(node, begin, end, bounds);
    uint32_t mid;
    // Deep chains (e.g. exponentially spaced boxes) fall back to median splits so the
    // recursion stays shallow (depth <= 64 + log2 n).
    if (best_axis >= 0 && depth < 64) {
      const int a = best_axis;
      auto* split = std::stable_partition(items.data() + begin, items.data() + end, [&](uint32_t it) {
        return bin_of(centroid[3 * size_t(it) + a], a) <= best_bin;
      });
      mid = uint32_t(split - items.data());
    } else {
      mid = begin + count / 2;  // centroids coincide: any split is as good
    }
    if (mid == begin || mid == end) mid = begin + count / 2;
    NvNode& n = nodes[node];
    for (int a = 0; a < 3; ++a) {
      n.bounds_min[a] = bounds.lo[a];
      n.bounds_max[a] = bounds.hi[a];
    }
    n.count = 0;
    const uint32_t left = uint32_t(nodes.size());
    nodes.emplace_back();
    build(left, begin, mid, depth + 1);
    const uint32_t right = uint32_t(nodes.size());
    nodes.emplace_back();
    nodes[node].first = right;
    build(right, mid, end, depth + 1);
  }
};

}  // namespace

Box triangle_box(const float v[9]) {
  Box b = Box::empty();
  for (int k = 0; k < 3; ++k) b.grow_point(v + 3 * k);
  return b;
}

Box transform_box(const Box& local, const float m[12]) {
  Box out = Box::empty();
  for (int c = 0; c < 8; ++c) {
    const double p[3] = {(c & 1) ? local.hi[0] : local.lo[0], (c & 2) ? local.hi[1] : local.lo[1],
                         (c & 4) ? local.hi[2] : local.lo[2]};
    for (int r = 0; r < 3; ++r) {
      const double w = m[4 * r] * p[0] + m[4 * r + 1] * p[1] + m[4 * r + 2] * p[2] + m[4 * r + 3];
      // Round outwards so the float box contains the exact one.
      const float f = float(w);
      const float lo = double(f) > w ? std::nextafter(f, -std::numeric_limits<float>::infinity()) : f;
      const float hi = double(f) < w ? std::nextafter(f, std::numeric_limits<float>::infinity()) : f;
      out.lo[r] = std::min(out.lo[r], lo);
      out.hi[r] = std::max(out.hi[r], hi);
    }
  }
  return out;
}

Tree build_tree(std::span<const Box> boxes) {
  Tree t;
  if (boxes.empty()) return t;
  Builder b;
  b.boxes = boxes;
  b.centroid.resize(boxes.size() * 3);
  b.items.resize(boxes.size());
  for (size_t i = 0; i < boxes.size(); ++i) {
    b.items[i] = uint32_t(i);
    for (int a = 0; a < 3; ++a) {
      // Halves first: lo + hi would overflow to inf for coordinates near FLT_MAX.
      b.centroid[3 * i + a] = boxes[i].lo[a] * 0.5f + boxes[i].hi[a] * 0.5f;
    }
  }
  b.nodes.reserve(2 * boxes.size());
  b.nodes.emplace_back();
  b.build(0, 0, uint32_t(boxes.size()), 0);
  t.nodes = std::move(b.nodes);
  t.order = std::move(b.items);
  return t;
}

}  // namespace clastrace::engine::nv
