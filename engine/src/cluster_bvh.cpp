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
    // Accumulate in locals: writing through `node` each step defeats vectorization.
    float lo0 = INFINITY, lo1 = INFINITY, lo2 = INFINITY, hi0 = -INFINITY, hi1 = -INFINITY, hi2 = -INFINITY;
    float cl0 = INFINITY, cl1 = INFINITY, cl2 = INFINITY, ch0 = -INFINITY, ch1 = -INFINITY, ch2 = -INFINITY;
    for (uint32_t i = task.begin; i < task.end; ++i) {
      const uint32_t t = s.perm[i];
      const float* mn = s.tri_min[t];
      const float* mx = s.tri_max[t];
      const float* c = s.centroid[t];
      lo0 = std::min(lo0, mn[0]); lo1 = std::min(lo1, mn[1]); lo2 = std::min(lo2, mn[2]);
      hi0 = std::max(hi0, mx[0]); hi1 = std::max(hi1, mx[1]); hi2 = std::max(hi2, mx[2]);
      cl0 = std::min(cl0, c[0]); cl1 = std::min(cl1, c[1]); cl2 = std::min(cl2, c[2]);
      ch0 = std::max(ch0, c[0]); ch1 = std::max(ch1, c[1]); ch2 = std::max(ch2, c[2]);
    }
    node.lo[0] = lo0; node.lo[1] = lo1; node.lo[2] = lo2;
    node.hi[0] = hi0; node.hi[1] = hi1; node.hi[2] = hi2;
    const float clo[3] = {cl0, cl1, cl2}, chi[3] = {ch0, ch1, ch2};
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
