// BVH over the triangles of one cluster (at most 256): split at the middle of the
// centroid bounds along their longest axis, median split when that leaves a side empty,
// leaves of up to kMaxLeafSize triangles. No allocation: everything lives in BvhScratch.
#include "cluster_internal.h"

#include <algorithm>
#include <cmath>

namespace clastrace::engine::detail {

namespace {

struct Task {
  uint16_t node, begin, end;
};

}  // namespace

void build_bvh(const float* positions, const uint32_t* indices, const uint8_t* active_list, uint32_t n, BvhScratch& s) {
  s.node_count = 0;
  if (n == 0) return;
  for (uint32_t i = 0; i < n; ++i) {
    const uint32_t t = active_list[i];
    s.perm[i] = uint8_t(t);
    const float* a = positions + 3 * indices[3 * t + 0];
    const float* b = positions + 3 * indices[3 * t + 1];
    const float* c = positions + 3 * indices[3 * t + 2];
    for (int k = 0; k < 3; ++k) {
      const float lo = std::min(a[k], std::min(b[k], c[k]));
      const float hi = std::max(a[k], std::max(b[k], c[k]));
      s.tri_min[t][k] = lo;
      s.tri_max[t][k] = hi;
      // Half-sum avoids overflow near FLT_MAX.
      // Half-sum avoids overflow near FLT_MAX; -inf..+inf gives NaN, which must not
      // reach the comparisons below.
      const float c = lo * 0.5f + hi * 0.5f;
      s.centroid[t][k] = c == c ? c : 0.0f;
    }
  }

  Task stack[kMaxNodes];
  int sp = 0;
  s.node_count = 1;
  stack[sp++] = {0, 0, uint16_t(n)};
  while (sp > 0) {
    const Task task = stack[--sp];
    BvhScratch::Node& node = s.nodes[task.node];
    float clo[3], chi[3];
    for (int k = 0; k < 3; ++k) {
      node.lo[k] = clo[k] = INFINITY;
      node.hi[k] = chi[k] = -INFINITY;
    }
    for (uint32_t i = task.begin; i < task.end; ++i) {
      const uint32_t t = s.perm[i];
      for (int k = 0; k < 3; ++k) {
        node.lo[k] = std::min(node.lo[k], s.tri_min[t][k]);
        node.hi[k] = std::max(node.hi[k], s.tri_max[t][k]);
        clo[k] = std::min(clo[k], s.centroid[t][k]);
        chi[k] = std::max(chi[k], s.centroid[t][k]);
      }
    }
    const uint32_t count = task.end - task.begin;
    if (count <= kMaxLeafSize) {
      node.first = task.begin;
      node.count = uint16_t(count);
      continue;
    }
    int axis = 0;
    float best = chi[0] - clo[0];
    for (int k = 1; k < 3; ++k)
      if (chi[k] - clo[k] > best) {
        best = chi[k] - clo[k];
        axis = k;
      }
    const float split = clo[axis] * 0.5f + chi[axis] * 0.5f;
    uint8_t* first = s.perm + task.begin;
    uint8_t* last = s.perm + task.end;
    uint8_t* mid = std::partition(first, last, [&](uint8_t t) { return s.centroid[t][axis] < split; });
    if (mid == first || mid == last) {
      mid = first + count / 2;
      std::nth_element(first, mid, last, [&](uint8_t x, uint8_t y) {
        if (s.centroid[x][axis] != s.centroid[y][axis]) return s.centroid[x][axis] < s.centroid[y][axis];
        return x < y;  // deterministic order for equal centroids
      });
    }
    const uint16_t left = uint16_t(s.node_count);
    s.node_count += 2;
    node.first = left;
    node.count = 0;
    const uint16_t m = uint16_t(task.begin + (mid - first));
    stack[sp++] = {uint16_t(left + 1), m, task.end};
    stack[sp++] = {left, task.begin, m};
  }
}

}  // namespace clastrace::engine::detail
