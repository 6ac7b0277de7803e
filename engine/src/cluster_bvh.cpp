// SPDX-License-Identifier: Apache-2.0
// BVH over the triangles of one cluster (at most 256): object-median splits along the
// longest axis of the node's centroid bounds, rounded to whole leaves of kMaxLeafSize
// triangles. No allocation: everything lives on the stack or in BvhScratch.
//
// Why it is fast: the triangles are sorted once per axis (centroids quantized to 10 bits
// inside the cluster's centroid bounds, a two-pass 5-bit radix sort, ties in triangle
// order), and every split keeps the three orders: the split axis's order is already split,
// the other two are partitioned stably in one pass each, from one of two buffers into the
// other, every element stored once at its final slot. A node's centroid extent is then
// its first and last triangle in each order, the median is a position, a leaf's box is taken
// when it is made and the interior boxes bottom-up once (each node from its children), so no
// level rereads its triangles to select, and none compares floats in a data-dependent branch;
// leaves and interior nodes are boxed apart, with no branch on the node's kind (one that
// mispredicted about every third node). The per-element loops carry
// `#pragma GCC unroll 4`: GCC at -O2 unrolls none of them, and their bodies are a few
// instructions beside the loop's own compare and branch. Orders written a byte at a time are
// not read back at once in wider loads: a load that spans several stores still pending cannot
// take their data and waits for them to reach the cache (a 16-wide SSSE3 partition that did
// so at every stage was 8% slower than this scalar one, for fewer instructions).
#include "cluster_internal.h"
#include "simd4.h"

#include <cstring>

namespace clastrace::engine::detail {

namespace {

constexpr uint32_t kKeyBits = 10;  // per axis; two radix passes of kDigitBits
constexpr uint32_t kDigitBits = kKeyBits / 2;
constexpr uint32_t kDigits = 1u << kDigitBits;
// Counts of the six digits (low and high on each axis), kept twice while counting: even
// triangles into the first six, odd ones into the second (count_keys says why).
constexpr int kCountArrays = 12;

// A node to split, its triangles' range in the orders, and which of the two order buffers
// holds each axis's order over that range (bit k for axis k).
struct Task {
    uint32_t node, begin, end, buffers;
};

// Tasks sit on the stack as 8-byte words, pushed by one store and popped by one load. As a
// struct of 16-bit fields GCC stored them field by field, and the pop's 8-byte load, spanning
// several stores, cannot take its data from them (store forwarding needs one store holding
// the whole load): it waited for every older store to reach the cache, the partition's
// hundreds of byte stores included, at every task.
using PackedTask = uint64_t;
PackedTask pack(const Task& t) {
    return PackedTask(t.node) | PackedTask(t.begin) << 16 | PackedTask(t.end) << 32 |
           PackedTask(t.buffers) << 48;
}
Task unpack(PackedTask w) {
    return {uint32_t(w & 0xFFFF), uint32_t(w >> 16 & 0xFFFF), uint32_t(w >> 32 & 0xFFFF),
            uint32_t(w >> 48)};
}

// A triangle's two radix digits on each axis, as the sort reads them: its low digits (x, y, z)
// in lo[0..2], its high digits in hi[0..2]; lane 3 unused. Bytes, one 8-byte store each.
struct Digits {
    uint8_t lo[4], hi[4];
};

// Splits a triangle's keys (lanes x, y, z, 0..1023) into its digits and counts them.
void count_digits(Int4 key, Digits& d, uint16_t (*hist)[kDigits]) {
#if defined(__SSE2__)
    // The six digits side by side in one register, each taken out of it for its count: no
    // store and reload of the keys, no scalar masks and shifts.
    const __m128i k16 = _mm_packs_epi32(key.v, key.v);
    const __m128i both = _mm_unpacklo_epi64(_mm_and_si128(k16, _mm_set1_epi16(kDigits - 1)),
                                            _mm_srli_epi16(k16, kDigitBits));
    _mm_storel_epi64(reinterpret_cast<__m128i*>(&d), _mm_packus_epi16(both, both));
    ++hist[0][_mm_extract_epi16(both, 0)];
    ++hist[2][_mm_extract_epi16(both, 1)];
    ++hist[4][_mm_extract_epi16(both, 2)];
    ++hist[1][_mm_extract_epi16(both, 4)];
    ++hist[3][_mm_extract_epi16(both, 5)];
    ++hist[5][_mm_extract_epi16(both, 6)];
#else
    alignas(16) int32_t q[4];
    store_int4(q, key);
    for (int k = 0; k < 4; ++k) {
        d.lo[k] = uint8_t(q[k] & (kDigits - 1));
        d.hi[k] = uint8_t(q[k] >> kDigitBits);
    }
    for (int k = 0; k < 3; ++k) {
        ++hist[2 * k][d.lo[k]];
        ++hist[2 * k + 1][d.hi[k]];
    }
#endif
}

// Sorts 0..n-1 by key (digits) on each axis k into order[k] (stable: equal keys stay in
// increasing index order). hist[2k] / hist[2k+1] hold the counts of the low / high digits,
// hist[6 + h] more counts of hist[h]'s digits; the passes use hist[0..5] alone.
void radix_sort3(const Digits* digits, uint32_t n, uint16_t (*hist)[kDigits],
                 uint8_t (*order)[kMaxTriangles]) {
    // Exclusive prefix sums (counts <= 256 fit 16 bits).
#if defined(__SSE2__)
    static_assert(kDigits % 8 == 0);
    for (int h = 0; h < 6; ++h) {
        __m128i carry = _mm_setzero_si128();
        for (uint32_t d = 0; d < kDigits; d += 8) {
            __m128i* const p = reinterpret_cast<__m128i*>(hist[h] + d);
            const __m128i* const q = reinterpret_cast<const __m128i*>(hist[h + 6] + d);
            __m128i x = _mm_add_epi16(_mm_loadu_si128(p), _mm_loadu_si128(q));
            x = _mm_add_epi16(x, _mm_slli_si128(x, 2));
            x = _mm_add_epi16(x, _mm_slli_si128(x, 4));
            x = _mm_add_epi16(x, _mm_slli_si128(x, 8));  // inclusive
            _mm_storeu_si128(p, _mm_add_epi16(_mm_slli_si128(x, 2), carry));
            const __m128i last = _mm_shufflehi_epi16(x, 0xFF);
            carry = _mm_add_epi16(carry, _mm_unpackhi_epi64(last, last));
        }
    }
#else
    for (int h = 0; h < 6; ++h) {
        uint32_t sum = 0;
        for (uint32_t d = 0; d < kDigits; ++d) {
            const uint32_t c = hist[h][d] + hist[h + 6][d];
            hist[h][d] = uint16_t(sum);
            sum += c;
        }
    }
#endif
    // The three axes go through each pass together: three independent chains of counter
    // updates for the out-of-order core to overlap. Written out per axis: GCC at -O2 keeps a
    // loop over k and recomputes every address from k (about twice the instructions).
    uint8_t tmp[3][kMaxTriangles];
    uint16_t *const lo0 = hist[0], *const lo1 = hist[2], *const lo2 = hist[4];
#pragma GCC unroll 4
    for (size_t i = 0; i < n; ++i) {
        tmp[0][lo0[digits[i].lo[0]]++] = uint8_t(i);
        tmp[1][lo1[digits[i].lo[1]]++] = uint8_t(i);
        tmp[2][lo2[digits[i].lo[2]]++] = uint8_t(i);
    }
    uint16_t *const hi0 = hist[1], *const hi1 = hist[3], *const hi2 = hist[5];
#pragma GCC unroll 4
    for (size_t j = 0; j < n; ++j) {
        const size_t i0 = tmp[0][j], i1 = tmp[1][j], i2 = tmp[2][j];
        order[0][hi0[digits[i0].hi[0]]++] = uint8_t(i0);
        order[1][hi1[digits[i1].hi[1]]++] = uint8_t(i1);
        order[2][hi2[digits[i2].hi[2]]++] = uint8_t(i2);
    }
}

// An exact copy of count (kLeast..N) triangle indices without a branch on the count (a memcpy
// call of a variable size mispredicts in its size classes): N byte copies, those past kLeast
// with the last index repeated. Bytewise, not in wider pieces: the indices were just written
// a byte at a time, and a wider load that spans several pending stores cannot be forwarded
// from them (it waits for them).
template <size_t kLeast, size_t N>
void copy_up_to(uint8_t* dst, const uint8_t* src, size_t count) {
    const size_t last = count - 1;
#pragma GCC unroll 8
    for (size_t k = 0; k < N; ++k) {
        const size_t at = k < kLeast || k < last ? k : last;
        dst[at] = src[at];
    }
}

// Whether order[0..n) is 0, 1, ..., n - 1, 16 bytes at a time where the target has SSE2
// (order is readable up to kMaxTriangles; the bytes past n are not looked at).
bool is_identity(const uint8_t* order, uint32_t n) {
#if defined(__SSE2__)
    static_assert(kMaxTriangles % 16 == 0);
    __m128i expected = _mm_setr_epi8(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    const __m128i step = _mm_set1_epi8(16);
    uint32_t i = 0;
    for (; i + 16 <= n; i += 16) {
        const __m128i got = _mm_loadu_si128(reinterpret_cast<const __m128i*>(order + i));
        if (_mm_movemask_epi8(_mm_cmpeq_epi8(got, expected)) != 0xFFFF) return false;
        expected = _mm_add_epi8(expected, step);
    }
    if (i == n) return true;
    const __m128i got = _mm_loadu_si128(reinterpret_cast<const __m128i*>(order + i));
    const uint32_t equal = uint32_t(_mm_movemask_epi8(_mm_cmpeq_epi8(got, expected)));
    const uint32_t wanted = (1u << (n - i)) - 1u;
    return (equal & wanted) == wanted;
#else
    uint32_t moved = 0;
    for (uint32_t j = 0; j < n; ++j) moved |= order[j] ^ j;
    return moved == 0;
#endif
}

// A leaf's box over its 1..4 triangles: four loads, the last triangle repeated (min and max
// fold it to the same box, ties included), so no branch on the count.
[[gnu::always_inline]] inline void fit_leaf(BvhScratch& s, const uint8_t* tris, size_t count,
                                            BvhScratch::Node& node) {
    const size_t last = count - 1;
    const size_t t1 = tris[last < 1 ? last : 1], t2 = tris[last < 2 ? last : 2], t3 = tris[last];
    Float4 lo = load4(s.tri_min[tris[0]]), hi = load4(s.tri_max[tris[0]]);
    lo = min4(lo, load4(s.tri_min[t1]));
    hi = max4(hi, load4(s.tri_max[t1]));
    lo = min4(lo, load4(s.tri_min[t2]));
    hi = max4(hi, load4(s.tri_max[t2]));
    lo = min4(lo, load4(s.tri_min[t3]));
    hi = max4(hi, load4(s.tri_max[t3]));
    store4(node.lo, lo);
    store4(node.hi, hi);
}

// The leaf of `count` triangles at leaf_order[first..]: its box and link. Inlined: a call
// with its five arguments cost a third of a leaf.
[[gnu::always_inline]] inline void make_leaf(BvhScratch& s, const uint8_t* leaf_order,
                                             uint32_t first, uint32_t count,
                                             BvhScratch::Node& node) {
    fit_leaf(s, leaf_order + first, count, node);
    node.link = uint16_t(kLeafBit | ((count - 1u) << 8) | first);
}

// Interior boxes bottom-up, `interior` in the order the nodes were split: a node's children
// were split after it, so the reverse order meets every child first.
void fit_interior_boxes(BvhScratch& s, const uint16_t* interior, size_t count) {
    for (size_t k = count; k-- > 0;) {
        BvhScratch::Node& node = s.nodes[interior[k]];
        const BvhScratch::Node& l = s.nodes[node.link];
        const BvhScratch::Node& r = s.nodes[node.link + 1];
        store4(node.lo, min4(load4(l.lo), load4(r.lo)));
        store4(node.hi, max4(load4(l.hi), load4(r.hi)));
    }
}

// The digit counts set to 0 by 16-byte stores where the target has SSE2. GCC zeroes the
// array (`= {}`, or a loop storing zeros it can see) with `rep stos`, microcoded, whose stores
// the counting's loads of the same bytes right after cannot be forwarded from: they wait for
// them to reach the cache. The empty asm hides that the stored value is zero.
void zero_counts(uint16_t (*hist)[kDigits]) {
#if defined(__SSE2__) && defined(__GNUC__)
    static_assert(kDigits % 8 == 0);
    __m128i zero = _mm_setzero_si128();
    asm("" : "+x"(zero));
    for (int h = 0; h < kCountArrays; ++h)
        for (uint32_t d = 0; d < kDigits; d += 8)
            _mm_store_si128(reinterpret_cast<__m128i*>(hist[h] + d), zero);
#else
    std::memset(hist, 0, kCountArrays * sizeof *hist);
#endif
}

// Each triangle's 10-bit keys per axis, monotone in its centroid (so sorting them sorts the
// centroids up to ties inside one step of extent / 1024), as digits, and the digits' counts.
// Halves again keep extents finite. Neighbouring triangles often share a digit (a cluster's
// triangles come in mesh order), and the increments of one counter in a row wait for each
// other through memory: the odd triangles count into their own six arrays, which halves those
// chains (the device's Xeon built WusonOBJ 1.1-1.26x as fast with this; docs/benchmarks.md,
// cluster build round 11).
void count_keys(const BvhScratch& s, uint32_t n, Digits* digits, uint16_t (*hist)[kDigits]) {
    const Float4 half = splat(0.5f);
    const Float4 base = load4(s.centroid_min) * half;
    const Float4 scale =
        splat(float(1u << kKeyBits)) /
        (load4(s.centroid_max) * half - base);  // inf or NaN for a flat axis: keys 0
    const Float4 zero = splat(0.0f), top = splat(float((1u << kKeyBits) - 1));
    const auto key = [&](uint32_t i) {
        // max4(x, zero) turns NaN into 0.
        return to_int(min4(max4((load4(s.centroid[i]) * half - base) * scale, zero), top));
    };
    uint32_t i = 0;
    for (; i + 1 < n; i += 2) {
        count_digits(key(i), digits[i], hist);
        count_digits(key(i + 1), digits[i + 1], hist + 6);
    }
    if (i < n) count_digits(key(i), digits[i], hist);
}

// The triangles in key order along each axis (ties in triangle order).
void sort_along_axes(const BvhScratch& s, uint32_t n, uint8_t (*order)[kMaxTriangles]) {
    Digits digits[kMaxTriangles];
    alignas(16) uint16_t hist[kCountArrays][kDigits];
    zero_counts(hist);
    count_keys(s, n, digits, hist);
    radix_sort3(digits, n, hist, order);
}

}  // namespace

bool build_bvh(const uint8_t* active_list, uint32_t n, BvhScratch& s, uint8_t* order_out) {
    s.node_count = 0;
    if (n == 0) return true;

    const float(*const centroid)[4] = s.centroid;
    // Two buffers per axis: a split reads the other two axes' orders from one and writes them
    // partitioned into the other, each element stored once. Partitioned in place, every
    // element was stored twice (at the next left slot and at the next slot of a buffer of the
    // rights, copied back after the loop in 8-byte moves over those byte stores), and the
    // in-place stores went to the array the loop was reading: the device's Xeon built
    // WusonOBJ 1.6x as fast with this (docs/benchmarks.md, cluster build round 11).
    uint8_t order[2][3][kMaxTriangles];
    sort_along_axes(s, n, order[0]);

    // Top-down: node numbering is depth first, left subtree first, the two children of a node
    // next to each other.
    uint8_t side[kMaxTriangles];
    // Each leaf's triangles at its range: the BVH order itself when the active triangles are
    // all of them.
    uint8_t own_leaf_order[kMaxTriangles];
    uint8_t* const leaf_order = active_list ? own_leaf_order : order_out;
    PackedTask stack[kMaxNodes];
    uint16_t interior[kMaxNodes];  // in the order they were split
    size_t n_interior = 0;
    int sp = 0;
    s.node_count = 1;
    if (n <= kMaxLeafSize) {  // a root leaf: its triangles along x
        std::memcpy(leaf_order, order[0][0], n);
        make_leaf(s, leaf_order, 0, n, s.nodes[0]);
    } else {
        stack[sp++] = pack({0, 0, n, 0});
    }
    // Only nodes that split are tasks: their parent makes a leaf where it splits (a leaf test
    // at each task mispredicted about every third node).
    while (sp > 0) {
        const Task task = unpack(stack[--sp]);
        BvhScratch::Node& node = s.nodes[task.node];
        const uint32_t b = task.begin, e = task.end, count = e - b;
        uint8_t* const ox = order[task.buffers & 1][0];
        uint8_t* const oy = order[task.buffers >> 1 & 1][1];
        uint8_t* const oz = order[task.buffers >> 2 & 1][2];
        uint8_t* const axis_order[3] = {ox, oy, oz};
        int axis = 0;
        float best = centroid[ox[e - 1]][0] - centroid[ox[b]][0];
        const float extent_y = centroid[oy[e - 1]][1] - centroid[oy[b]][1];
        if (extent_y > best) {
            best = extent_y;
            axis = 1;
        }
        const float extent_z = centroid[oz[e - 1]][2] - centroid[oz[b]][2];
        if (extent_z > best) axis = 2;
        const uint8_t* const split_order = axis_order[axis];
        // Object median rounded to whole leaves: left gets half of the leaves (full ones), so
        // the tree has the fewest nodes (2 * ceil(n / 4) - 1) and stays balanced.
        const uint32_t leaves = (count + kMaxLeafSize - 1) / kMaxLeafSize;
        const uint32_t left_count = kMaxLeafSize * ((leaves + 1) / 2);
        const uint32_t m = b + left_count;
        const uint16_t left = uint16_t(s.node_count);
        s.node_count += 2;
        node.link = left;
        interior[n_interior++] = uint16_t(task.node);
        if (count <= 2 * kMaxLeafSize) {
            // Both children are leaves: they need no sorted orders, only their triangles.
            // A task has more than kMaxLeafSize triangles.
            copy_up_to<kMaxLeafSize + 1, 2 * kMaxLeafSize>(leaf_order + b, split_order + b, count);
            make_leaf(s, leaf_order, b, left_count, s.nodes[left]);
            make_leaf(s, leaf_order, m, count - left_count, s.nodes[left + 1]);
            continue;
        }
        // Every triangle of a left child (odd node numbers) still has side 0 from its parent's
        // split, and of a right child (even, not the root) side 1: nodes in between belong to
        // the left sibling's subtree and set only their own triangles'. So only the side that
        // changes is written.
        const bool left_child = task.node % 2 == 1, right_child = !left_child && task.node;
        if (!left_child) {
#pragma GCC unroll 4
            for (size_t j = b; j < m; ++j) side[split_order[j]] = 0;
        }
        if (!right_child) {
#pragma GCC unroll 4
            for (size_t j = m; j < e; ++j) side[split_order[j]] = 1;
        }
        // The other two axes from a table: a select on `axis` compiles to a branch that
        // mispredicts (the axis follows the data).
        static constexpr uint8_t kOtherAxes[3][2] = {{1, 2}, {0, 2}, {0, 1}};
        const uint32_t k1 = kOtherAxes[axis][0], k2 = kOtherAxes[axis][1];
        const uint32_t from1 = task.buffers >> k1 & 1, from2 = task.buffers >> k2 & 1;
        const uint8_t* const src1 = order[from1][k1] + b;
        const uint8_t* const src2 = order[from2][k2] + b;
        uint8_t* const dst1 = order[from1 ^ 1][k1] + b;
        uint8_t* const dst2 = order[from2 ^ 1][k2] + b;
        // Their orders, partitioned stably in one loop (two independent chains), each element
        // stored once, at the next slot of its side: no branch, the slot is a select.
        // Pointer-sized counters: no zero extension before each address.
        size_t r1 = 0, r2 = 0;
#pragma GCC unroll 4
        for (size_t j = 0; j < count; ++j) {
            const size_t i1 = src1[j], i2 = src2[j];
            const size_t s1 = side[i1], s2 = side[i2];
            dst1[s1 ? left_count + r1 : j - r1] = uint8_t(i1);
            dst2[s2 ? left_count + r2 : j - r2] = uint8_t(i2);
            r1 += s1;
            r2 += s2;
        }
        const uint32_t buffers = task.buffers ^ (1u << k1) ^ (1u << k2);
        // More than 8 triangles leave at least 8 on the left (a node), and on the right 1-4
        // (a leaf, its triangles from the split axis's order) or more (a node).
        if (count - left_count <= kMaxLeafSize) {
            copy_up_to<1, kMaxLeafSize>(leaf_order + m, split_order + m, count - left_count);
            make_leaf(s, leaf_order, m, count - left_count, s.nodes[left + 1]);
        } else {
            stack[sp++] = pack({left + 1u, m, e, buffers});
        }
        stack[sp++] = pack({left, b, m, buffers});
    }

    fit_interior_boxes(s, interior, n_interior);
    if (!active_list) return is_identity(order_out, n);
    uint32_t moved = 0;
#pragma GCC unroll 4
    for (size_t j = 0; j < n; ++j) {
        const uint8_t t = active_list[leaf_order[j]];
        order_out[j] = t;
        moved |= t ^ uint32_t(j);
    }
    return moved == 0;
}

}  // namespace clastrace::engine::detail
