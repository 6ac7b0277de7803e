// BVH over the triangles of one cluster (at most 256): object-median splits along the
// longest axis of the centroid bounds, rounded to whole leaves of kMaxLeafSize triangles.
// No allocation: everything lives in BvhScratch.
#include "cluster_internal.h"

#include <algorithm>
#include <cmath>
#include <cstring>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace clastrace::engine::detail {

namespace {

struct Task {
  uint16_t node, begin, end;
};

}  // namespace

void build_bvh(const float* positions, const uint32_t* indices, const uint8_t* active_list, uint32_t n, BvhScratch& s) {
  s.node_count = 0;
  if (n == 0) return;
  uint64_t axis_key[3][kMaxTriangles];
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
      // Half-sum avoids overflow near FLT_MAX; -inf..+inf gives NaN, which must not
      // reach the comparisons below.
      const float m = lo * 0.5f + hi * 0.5f;
      s.centroid[t][k] = m == m ? m : 0.0f;
      // Selection key per axis, computed once: the centroid's order-preserving bit pattern
      // above the triangle index.
      uint32_t u;
      std::memcpy(&u, &s.centroid[t][k], 4);
      u ^= (u >> 31) ? 0xFFFFFFFFu : 0x80000000u;
      axis_key[k][t] = (uint64_t(u) << 8) | t;
    }
    s.tri_min[t][3] = s.tri_max[t][3] = s.centroid[t][3] = 0.0f;
  }

#if defined(__SSE2__)
  // Each node's box and centroid box are gathered where its triangles were last visited
  // (the root by its own pass, a child in its parent's write-back of the selection), in
  // the same perm order as a separate pass over the child's range, so the results are
  // identical and each level reads its triangles once instead of twice.
  alignas(16) float cbox[kMaxNodes][2][4];
  {
    __m128 lo = _mm_set1_ps(INFINITY), hi = _mm_set1_ps(-INFINITY), cl = lo, ch = hi;
    for (uint32_t i = 0; i < n; ++i) {
      const uint32_t t = s.perm[i];
      lo = _mm_min_ps(lo, _mm_load_ps(s.tri_min[t]));
      hi = _mm_max_ps(hi, _mm_load_ps(s.tri_max[t]));
      const __m128 c = _mm_load_ps(s.centroid[t]);
      cl = _mm_min_ps(cl, c);
      ch = _mm_max_ps(ch, c);
    }
    alignas(16) float lo4[4], hi4[4];
    _mm_store_ps(lo4, lo);
    _mm_store_ps(hi4, hi);
    _mm_store_ps(cbox[0][0], cl);
    _mm_store_ps(cbox[0][1], ch);
    for (int k = 0; k < 3; ++k) {
      s.nodes[0].lo[k] = lo4[k];
      s.nodes[0].hi[k] = hi4[k];
    }
  }
#endif
  Task stack[kMaxNodes];
  int sp = 0;
  s.node_count = 1;
  stack[sp++] = {0, 0, uint16_t(n)};
  while (sp > 0) {
    const Task task = stack[--sp];
    BvhScratch::Node& node = s.nodes[task.node];
    float clo[4], chi[4];
#if defined(__SSE2__)
    std::memcpy(clo, cbox[task.node][0], sizeof clo);
    std::memcpy(chi, cbox[task.node][1], sizeof chi);
#else
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
#endif
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
    // Object-median split rounded to whole leaves: left gets half of the leaves (full ones),
    // so the tree has the fewest nodes (2 * ceil(n / 4) - 1) and stays balanced. Keys pack
    // the centroid's order-preserving bit pattern with the triangle index, which makes the
    // selection branch-light and deterministic on ties.
    const uint32_t leaves = (count + kMaxLeafSize - 1) / kMaxLeafSize;
    const uint32_t left_count = kMaxLeafSize * ((leaves + 1) / 2);
    uint64_t keys[kMaxTriangles];
    for (uint32_t i = 0; i < count; ++i) {
      keys[i] = axis_key[axis][s.perm[task.begin + i]];
    }
    std::nth_element(keys, keys + left_count, keys + count);
    const uint16_t left = uint16_t(s.node_count);
    s.node_count += 2;
    node.first = left;
    node.count = 0;
    uint8_t* first = s.perm + task.begin;
#if defined(__SSE2__)
    for (int side = 0; side < 2; ++side) {
      const uint32_t b = side ? left_count : 0, e = side ? count : left_count;
      __m128 lo = _mm_set1_ps(INFINITY), hi = _mm_set1_ps(-INFINITY), cl = lo, ch = hi;
      for (uint32_t i = b; i < e; ++i) {
        const uint32_t t = uint32_t(keys[i] & 0xFF);
        first[i] = uint8_t(t);
        lo = _mm_min_ps(lo, _mm_load_ps(s.tri_min[t]));
        hi = _mm_max_ps(hi, _mm_load_ps(s.tri_max[t]));
        const __m128 c = _mm_load_ps(s.centroid[t]);
        cl = _mm_min_ps(cl, c);
        ch = _mm_max_ps(ch, c);
      }
      alignas(16) float lo4[4], hi4[4];
      _mm_store_ps(lo4, lo);
      _mm_store_ps(hi4, hi);
      _mm_store_ps(cbox[left + side][0], cl);
      _mm_store_ps(cbox[left + side][1], ch);
      BvhScratch::Node& child = s.nodes[left + side];
      for (int k = 0; k < 3; ++k) {
        child.lo[k] = lo4[k];
        child.hi[k] = hi4[k];
      }
    }
#else
    for (uint32_t i = 0; i < count; ++i) first[i] = uint8_t(keys[i] & 0xFF);
#endif
    const uint16_t m = uint16_t(task.begin + left_count);
    stack[sp++] = {uint16_t(left + 1), m, task.end};
    stack[sp++] = {left, task.begin, m};
  }
}

}  // namespace clastrace::engine::detail
