// SPDX-License-Identifier: Apache-2.0
// The NV traversal's own layout of a tree (issue 22): the stored binary tree (NvNode, which
// replay compares byte for byte and therefore stays as it is) collapsed into 8-wide nodes
// tested with AVX2 where the CPU has it, 4-wide nodes tested with SSE elsewhere (SimdPath),
// child boxes in SoA lanes, built when a scene is opened (nv_trace.cpp keeps it beside the
// copied records) and traversed near child first with one SIMD slab test per node.
//
// The SIMD box test is conservative for every ray it accepts (WideRay::usable): for a
// kDouble ray it never culls a box that the exact ray (double origin and direction) meets
// within [tmin, tmax], so it keeps every box the scalar double slab test (geometry/slab.h)
// keeps; for a kFloat32 ray it keeps every box the scalar float32 test (float32.h) keeps. The
// triangle test alone decides the hits. Rays it cannot bound that way
// (non-finite or huge origins, direction components whose inverse leaves 2^±100) take the
// scalar walk over the binary tree.
#pragma once

#include "clastrace/engine/nv_format.h"
#include "geometry/ray.h"
#include "geometry/triangle4.h"
#include "huge_pages.h"
#include "simd4.h"
#include "spill_stack.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstddef>
#include <cstring>
#include <optional>
#include <vector>

#if defined(__x86_64__) && defined(__SSE2__) && defined(__GNUC__)
// The 8-wide box test and walk, compiled for AVX2 in functions of their own (target
// attribute) and chosen at run time (active_simd_path); the rest of the engine stays SSE2.
#define CLASTRACE_AVX2_PATH 1
#define CLASTRACE_TARGET_AVX2 __attribute__((target("avx2")))
#include <immintrin.h>
#endif

namespace clastrace::engine::detail {

// Children of a collapsed tree, W of them (4 for the SSE path, 8 for the AVX2 path): their
// boxes by axis and lane, each child an inner wide node (count 0: `child` indexes the tree's
// nodes) or a leaf: `count` records from `child` on, those of a stored leaf or of a stored
// subtree of at most 12 contiguous records. Unused lanes have count kWideEmptyLane. Aligned
// to cache lines. Trees that cannot be quantized (below) keep the 4-wide form of this.
inline constexpr uint32_t kWideEmptyLane = 0xFFFFFFFFu;
template <int W>
struct alignas(64) FloatWideNode {
    float lo[3][W];
    float hi[3][W];
    uint32_t child[W];
    uint32_t count[W];
};
using WideNode = FloatWideNode<4>;
static_assert(sizeof(WideNode) == 128);

// The AVX2 path's nodes: the stored boxes themselves, eight children to a node, each lane's
// box the hull of its two bounds (lo <= hi, which the 8-wide test's choice of planes by the
// ray's signs relies on) and every unused lane lo = +inf, hi = -inf, which no ray meets. One
// 32-byte load a plane and no arithmetic before the slab test (the quantized bytes cost a
// widening, a conversion, a multiply and an add a plane: ~19 instructions a node). The box
// test reads the first three cache lines (the planes), the children and counts in the fourth
// only for the children hit.
using WideNode8 = FloatWideNode<8>;
static_assert(sizeof(WideNode8) == 256);
static_assert(offsetof(WideNode8, child) == 192);

// The 4-wide node with each child's box as bytes in the frame of the union of the four (per
// axis, `origin` and a power-of-two step 2^exponent, so q * step is exact and origin + q * step
// rounds once). The bytes are rounded outward at build time, checked on the very arithmetic
// the traversal runs (dequantized): every dequantized box contains the stored box it stands
// for, so the slab test on it culls nothing the stored one keeps.
// count: 0 inner, 1-254 a leaf's records, kQuantizedEmptyLane unused. One cache line.
inline constexpr uint8_t kQuantizedEmptyLane = 0xFF;
inline constexpr uint32_t kQuantizedMaxLeaf = 254;
struct alignas(64) QuantizedWideNode {
    float origin[3];
    int8_t exponent[3];  // in [-126, 127]: the step is a normal float
    uint8_t used;        // bit k: lane k holds a child (count[k] != kQuantizedEmptyLane)
    uint8_t qlo[3][4];
    uint8_t qhi[3][4];
    uint32_t child[4];
    uint8_t count[4];
};
static_assert(sizeof(QuantizedWideNode) == 64);

// The step 2^e as a float (e in [-126, 127]).
inline float quantization_step(int8_t e) {
    const uint32_t bits = uint32_t(int32_t(e) + 127) << 23;
    float f;
    std::memcpy(&f, &bits, 4);
    return f;
}

// One dequantized bound: origin + q * step, each operation rounded once to float. The builder
// checks its rounding through this; the SIMD lanes (quantized_lanes) run the same two float
// operations (no contraction: the engine builds with -ffp-contract=off),
// lane by lane, and so give the same floats.
inline float dequantized(float origin, uint8_t q, int8_t exponent) {
    return origin + float(q) * quantization_step(exponent);
}

// The dequantized boxes of one axis's four lanes, in float lanes.
inline void quantized_lanes(const QuantizedWideNode& n, int axis, Float4* lo, Float4* hi) {
    const Float4 origin = splat(n.origin[axis]);
    const Float4 step = splat(quantization_step(n.exponent[axis]));
    *lo = origin + bytes_to_float4(n.qlo[axis]) * step;
    *hi = origin + bytes_to_float4(n.qhi[axis]) * step;
}

// Which box test and node width the traversal uses. kAvx2: 8-wide float nodes tested eight
// at a time; kSse: 4-wide nodes, the reference and the path of CPUs without AVX2. Both keep
// every box the ray meets and test the same triangles exactly, so hits, t, barycentrics,
// facing and ties are the same; only the order of the leaves differs (which a
// terminate-on-first-hit ray may see as a different first hit).
enum class SimdPath { kSse, kAvx2 };
// kAvx2 where the CPU has AVX2, unless CLASTRACE_ENGINE_SIMD=sse (read once) or the test hook
// below says otherwise.
SimdPath active_simd_path();
// Test hook: the path of the trees made from now on (std::nullopt: back to the above). kAvx2
// on a CPU without AVX2 still gives kSse.
void force_simd_path(std::optional<SimdPath> path);
// Whether this CPU runs the AVX2 path.
bool cpu_has_avx2();

// A tree in the traversal's layout: `nodes8` on the AVX2 path; on the SSE path `quantized`
// when every node could be quantized (finite frames, leaves of at most kQuantizedMaxLeaf
// records), `nodes` otherwise. Element 0 of the one used is the root; all empty: nothing is
// ever hit. A node's inner children lie side by side, its leaves' groups
// too; the arrays lie on huge pages where large (huge_pages.h).
struct WideTree {
    HugePageVector<WideNode> nodes;
    HugePageVector<QuantizedWideNode> quantized;
    HugePageVector<WideNode8> nodes8;
    // Whether the leaves index groups of four triangles (group_leaf_triangles: `child` the first
    // group, `count` still the records) rather than records.
    bool leaf_groups = false;
    // The root box's center and the mean largest extent of the leaves' boxes, for
    // resolves_leaves.
    double center[3] = {0.0, 0.0, 0.0};
    double leaf_extent = 0.0;
    size_t node_count() const { return nodes.size() + quantized.size() + nodes8.size(); }
    size_t bytes() const {
        return nodes.size() * sizeof(WideNode) + quantized.size() * sizeof(QuantizedWideNode) +
               nodes8.size() * sizeof(WideNode8);
    }
};

// The wide tree of a checked binary tree (open_nv_object's rules: children after their
// parent) for `path`: 8-wide float nodes on kAvx2 (on a CPU that has it), else 4-wide,
// quantized where every node can be. A box with a NaN bound is left out with its subtree: no
// slab test ever accepts it.
WideTree make_wide_tree(const std::vector<NvNode>& nodes, SimdPath path = active_simd_path());
// The 4-wide tree with float boxes only (`nodes`).
WideTree make_float_wide_tree(const std::vector<NvNode>& nodes);
// The tree collapsed into 8-wide nodes as stored (boxes as the stored nodes give them, unused
// lanes zero with count kWideEmptyLane): what the kAvx2 tree's nodes8 are made from (tests
// compare the two).
std::vector<WideNode8> make_float_wide_nodes8(const std::vector<NvNode>& nodes);

// The triangles of `tree`'s leaves in groups of four (geometry/triangle4.h), a leaf's groups
// side by side in the order the leaves are laid out; each leaf's `child` becomes the index of
// its first group (tree->leaf_groups). `records` are the triangles the tree was built over;
// a leaf reaching past them keeps only the records that exist. On huge pages where large: the
// walk reads one group or two at random per leaf it enters.
HugePageVector<geometry::Triangle4> group_leaf_triangles(
    WideTree* tree, const std::vector<NvPrimitiveRecord>& records);

// A prepared ray in the SIMD box test's terms, as scalars; each path puts it into its lanes
// once per walk (WideRay4, WideRay8). usable false: use the scalar walk.
struct WideRay {
    bool usable = false;
    bool zero[3];           // direction component exactly 0: the origin is tested against the slab
    float origin[3];        // the origin rounded to float
    float inverse[3];       // 1 / direction rounded to float
    float origin_below[3];  // the float at or below / above the exact origin (zero axes only)
    float origin_above[3];
    float widen_down, widen_up;  // 1 -/+ the relative widening
    float widen_abs;             // the absolute widening (the origin's rounding, underflow)
    float tmin;                  // r.tmin rounded down
};

WideRay make_wide_ray(const geometry::PreparedRay& r);

// The three forms of a ray one traversal of a triangle tree tests with: the exact ray (the
// scalar walk, the exact triangle test), the SIMD box test's and the four-triangle filter's.
struct ObjectRays {
    geometry::PreparedRay exact;
    WideRay wide;
    geometry::Triangle4Ray triangles;
};

// The ObjectRays of a ray whose origin and direction are floats, finite, with no zero
// direction component (a bottom-level scene's rays, and those through an identity instance),
// in either mode: the fields the mode reads, equal to what prepare_ray (of `o` + 0, `d`,
// `mode`), make_wide_ray and make_triangle4_ray give, without the checks and the terms these
// need only for other rays (origins that are not floats, zero or non-finite components).
// False, and `out` unusable, for a ray that is not such a ray or that either SIMD form would
// not take (make_wide_ray's and make_triangle4_ray's range limits, on 1 / d in double): those
// take the three functions.
bool make_plain_object_rays(const float o[3], const float d[3], double tmin, double tmax,
                            TraversalMode mode, ObjectRays* out);

// Whether the SIMD box test still tells the tree's leaf boxes apart for a ray from `o`: its
// relative widening (2^-20 of each distance, make_wide_ray) at the ray's distance from the
// root's center is at most a quarter of a typical leaf. From farther away (1e-3 triangles seen
// from 4e4: the widening is 40 times a triangle) it accepts every leaf near the ray, and the
// double scalar walk, which culls them, is several times faster.
inline bool resolves_leaves(const WideTree& tree, const double o[3]) {
    double far = 0.0;
#pragma GCC unroll 3
    for (int a = 0; a < 3; ++a) far = std::max(far, std::fabs(o[a] - tree.center[a]));
    return !(far * 0x1p-20 > tree.leaf_extent * 0.25);
}

// The float at or above `t` (`t` itself when it is a float); +inf past FLT_MAX. Inline: the
// walks call it after every leaf.
inline float float_at_or_above(double t) {
    float f = float(t);
    if (__builtin_expect(double(f) < t, 0)) {
        // The next float up, by its bits (std::nextafter was a call, 30 instructions a ray):
        // f is below t, so neither NaN nor +inf; a zero steps to the least subnormal, a
        // positive f (FLT_MAX: to +inf) one up, a negative one (-inf: to -FLT_MAX) one down.
        uint32_t bits;
        std::memcpy(&bits, &f, 4);
        bits = f == 0.0f ? 1u : f > 0.0f ? bits + 1 : bits - 1;
        std::memcpy(&f, &bits, 4);
    }
    return f;
}

inline void lane_boxes(const WideNode& n, int axis, Float4* lo, Float4* hi) {
    *lo = load4(n.lo[axis]);
    *hi = load4(n.hi[axis]);
}
inline void lane_boxes(const QuantizedWideNode& n, int axis, Float4* lo, Float4* hi) {
    quantized_lanes(n, axis, lo, hi);
}
template <int W>
inline uint32_t lane_count(const FloatWideNode<W>& n, int k) {
    return n.count[k];
}
inline uint32_t lane_count(const QuantizedWideNode& n, int k) {
    return n.count[k] == kQuantizedEmptyLane ? kWideEmptyLane : n.count[k];
}
// Bit k: lane k holds a child.
inline unsigned used_lanes(const WideNode& n) {
    unsigned used = 0;
    for (int k = 0; k < 4; ++k) used |= unsigned(n.count[k] != kWideEmptyLane) << k;
    return used;
}
inline unsigned used_lanes(const QuantizedWideNode& n) { return n.used; }

// The children of `node` the ray meets within [tmin, tmax] (bit k = lane k) and their entry
// distances, each at or below the exact one. kZeroAxes: the ray may have a direction component
// exactly 0 (false: it has none, and the per-axis check drops out of the loop).
// WideRay in four lanes for the 4-wide box test.
struct WideRay4 {
    bool zero[3];
    Float4 origin[3], inverse[3];
    float origin_below[3], origin_above[3];
    Float4 widen_down, widen_up, widen_abs, tmin;
};

// Out of line: inlined, GCC rebuilt the lanes from the scalars at every box test (a load and a
// shuffle each, +2.8% instructions a ray on the SSE path) instead of reading them from memory.
WideRay4 make_wide_ray4(const WideRay& r);

template <bool kZeroAxes, class Node>
inline unsigned wide_hits(const WideRay4& r, const Node& node, float tmax, float entry[4]) {
    Float4 near_t = splat(-__builtin_inff()), far_t = splat(__builtin_inff());
    unsigned inside = 0xF;
#pragma GCC unroll 3
    for (int a = 0; a < 3; ++a) {
        Float4 lo, hi;
        lane_boxes(node, a, &lo, &hi);
        if (kZeroAxes && r.zero[a]) {
            inside &=
                le_lanes(lo, splat(r.origin_above[a])) & le_lanes(splat(r.origin_below[a]), hi);
            continue;
        }
        const Float4 t0 = (lo - r.origin[a]) * r.inverse[a];
        const Float4 t1 = (hi - r.origin[a]) * r.inverse[a];
        near_t = max4(near_t, min4(t0, t1));
        far_t = min4(far_t, max4(t0, t1));
    }
    // Widening after the per-axis max/min is the same as widening each axis (it is monotone),
    // with the largest axis's absolute term.
    near_t = min4(near_t * r.widen_down, near_t * r.widen_up) - r.widen_abs;
    far_t = max4(far_t * r.widen_down, far_t * r.widen_up) + r.widen_abs;
    near_t = max4(near_t, r.tmin);
    far_t = min4(far_t, splat(tmax));
    store4(entry, near_t);
    return le_lanes(near_t, far_t) & inside & used_lanes(node);
}

// An entry of a wide walk's stack: a child (count 0: an inner node, else a leaf's records) and
// the distance at which the ray enters its box.
struct WalkEntry {
    uint32_t child, count;
    float t;
};

// The entries a wide walk has yet to visit. Each visit pops one entry and pushes at most W - 1:
// depth x (W - 1) + 1 entries; the stored tree's depth is bounded by its node count, so deep
// (hostile) trees spill past 256.
using WalkStack = BurstStack<WalkEntry, 256, 8>;

// Lane k of `n`, which the box test hit (so it holds a child), as a stack entry.
template <class Node>
[[gnu::always_inline]] inline WalkEntry lane_child(const Node& n, int k, const float* entry) {
    return WalkEntry{n.child[k], uint32_t(n.count[k]), entry[k]};
}

// Fetches the bytes of child `c` (`prefetch(first, count)` for a leaf): rays are incoherent.
template <class Node, class Prefetch>
[[gnu::always_inline]] inline void fetch_child(const Node* nodes, const WalkEntry& c,
                                               Prefetch& prefetch) {
    if (c.count == 0) {
        const char* line = reinterpret_cast<const char*>(nodes + c.child);
        // Unrolled: the loop cost 4 instructions a line.
#pragma GCC unroll 4
        for (size_t at = 0; at < sizeof(Node); at += 64) __builtin_prefetch(line + at);
    } else {
        prefetch(c.child, c.count);
    }
}

// lane_child, fetched at once (a child that waits on the stack).
template <class Node, class Prefetch>
[[gnu::always_inline]] inline WalkEntry hit_child(const Node* nodes, const Node& n, int k,
                                                  const float* entry, Prefetch& prefetch) {
    const WalkEntry c = lane_child(n, k, entry);
    fetch_child(nodes, c, prefetch);
    return c;
}

// After a node whose box test hit `first` and the lanes in `more` (at least one): the others
// onto the stack farthest first, and the nearest returned, to be visited next without a push
// and a pop. Two children, the common case, take one comparison; more are sorted by
// insertion. Equal distances keep the lane order of the insertion sort the walks had before
// (the higher lane is visited first), so first-hit rays see the same leaves in the same order.
template <int W, class Node, class Prefetch>
[[gnu::always_inline]] inline WalkEntry order_children(const Node* nodes, const Node& n,
                                                       WalkEntry first, unsigned more,
                                                       const float* entry, Prefetch& prefetch,
                                                       WalkStack* stack) {
    const WalkEntry second = hit_child(nodes, n, __builtin_ctz(more), entry, prefetch);
    more &= more - 1;
    stack->make_room();
    if (more == 0) {
        if (first.t < second.t) {
            stack->push(second);
            return first;
        }
        stack->push(first);
        return second;
    }
    // Sorted in place on top of the stack, the nearest last: all but it are then pushed as
    // they lie (a copy of each from a local array cost about 12 instructions an entry).
    WalkEntry* order = stack->top();
    order[0] = first;
    int count = 1;
    for (WalkEntry c = second;;
         c = hit_child(nodes, n, __builtin_ctz(more), entry, prefetch), more &= more - 1) {
        int at = count++;
        while (at > 0 && order[at - 1].t < c.t) {
            order[at] = order[at - 1];
            --at;
        }
        order[at] = c;
        if (more == 0) break;
    }
    stack->grow(uint32_t(count - 1));
    return order[count - 1];
}

// Visits the leaves of a wide tree (`nodes`, W lanes a node) that the ray's [tmin, *tmax]
// reaches, nearest box first, skipping entries behind *tmax (`leaf(first, count)` lowers it;
// returns true to stop). `box_test(node, tmax, entry)` gives the lanes the ray meets (bit k =
// lane k) and their entry distances (wide_hits, wide8_hits). `prefetch(first, count)` is told
// of a leaf as soon as its box is hit. Always inlined into the one function of each path, so
// that the AVX2 box test inlines into the AVX2 walk (target attribute) and the SSE one into
// the SSE walk.
template <int W, class Node, class BoxTest, class Leaf, class Prefetch>
[[gnu::always_inline]] inline void walk_nodes(const HugePageVector<Node>& tree,
                                              const BoxTest& box_test, double* tmax, Leaf& leaf,
                                              Prefetch& prefetch) {
    if (tree.empty()) return;
    const Node* nodes = tree.data();
    WalkEntry entries[WalkStack::kSize];
    std::vector<WalkEntry> overflow;
    WalkStack stack(entries, &overflow);
    // *tmax rounded up to float, again after each leaf (only leaves lower *tmax). An entry
    // above it is above *tmax: its box holds no point of the ray within [tmin, *tmax]
    // (entries are at or below the exact ones). One between *tmax and the float above it is
    // still visited, which only costs a box test.
    float tmax_up = float_at_or_above(*tmax);
    // The entry visited next: the nearest child the node just visited hit (its entry is at or
    // below tmax_up, the box test's far end), else the first entry off the stack that is not
    // behind tmax_up.
    WalkEntry e{0, 0, -__builtin_inff()};
    for (;;) {
        if (e.count != 0) {
            if (leaf(e.child, e.count)) return;
            tmax_up = float_at_or_above(*tmax);
        } else {
            const Node& n = nodes[e.child];
            // The children's line asked for with the planes, not after the box test: a node
            // visited without a fetch (the root, a single hit child) missed on the planes and
            // then on its children, in turn (benchmarks.md, round 17).
            __builtin_prefetch(&n.child[0]);
            alignas(32) float entry[W];
            const unsigned hits = box_test(n, tmax_up, entry);
            if (hits != 0) {
                // A single child hit is visited next, its bytes read at once: no fetch
                // ahead (8 instructions a leaf, 4 a node, half the visits).
                const WalkEntry first = lane_child(n, __builtin_ctz(hits), entry);
                const unsigned more = hits & (hits - 1);
                if (more == 0) {
                    e = first;
                    continue;
                }
                fetch_child(nodes, first, prefetch);
                e = order_children<W>(nodes, n, first, more, entry, prefetch, &stack);
                continue;
            }
        }
        do {
            if (!stack.pop(&e)) return;
        } while (e.t > tmax_up);
    }
}

// walk_nodes over 4-wide nodes (float or quantized) with the SSE box test.
template <bool kZeroAxes, class Node, class Leaf, class Prefetch>
void walk_wide_nodes(const HugePageVector<Node>& nodes, const WideRay& wide_ray, double* tmax,
                     Leaf& leaf, Prefetch& prefetch) {
    const WideRay4 r = make_wide_ray4(wide_ray);
    const auto box_test = [&r](const Node& n, float tmax_up, float* entry) {
        return wide_hits<kZeroAxes>(r, n, tmax_up, entry);
    };
    walk_nodes<4>(nodes, box_test, tmax, leaf, prefetch);
}

#if defined(CLASTRACE_AVX2_PATH)

// WideRay in eight lanes for the 8-wide box test, and per axis the byte offsets (from a
// node's lo[0]) of the planes the ray enters and leaves a box by: with the signs of the
// direction known, the near plane is lo where it is positive and hi where it is negative,
// which gives the same distances as the min and max of the two (lo <= hi, 1 / d finite and
// not 0) without computing both.
struct WideRay8 {
    bool zero[3];
    int near_plane[3], far_plane[3];
    __m256 origin[3], inverse[3];
    __m256 origin_below[3], origin_above[3];
    __m256 widen_down, widen_up, widen_abs, tmin;
};

CLASTRACE_TARGET_AVX2 inline WideRay8 make_wide_ray8(const WideRay& r) {
    WideRay8 w;
    constexpr int kHi = int(offsetof(WideNode8, hi) - offsetof(WideNode8, lo));
    for (int a = 0; a < 3; ++a) {
        w.zero[a] = r.zero[a];
        w.origin[a] = _mm256_set1_ps(r.origin[a]);
        w.inverse[a] = _mm256_set1_ps(r.inverse[a]);
        w.origin_below[a] = _mm256_set1_ps(r.origin_below[a]);
        w.origin_above[a] = _mm256_set1_ps(r.origin_above[a]);
        const bool negative = r.inverse[a] < 0.0f;
        const int plane = int(sizeof(float)) * 8 * a;
        w.near_plane[a] = plane + (negative ? kHi : 0);
        w.far_plane[a] = plane + (negative ? 0 : kHi);
    }
    w.widen_down = _mm256_set1_ps(r.widen_down);
    w.widen_up = _mm256_set1_ps(r.widen_up);
    w.widen_abs = _mm256_set1_ps(r.widen_abs);
    w.tmin = _mm256_set1_ps(r.tmin);
    return w;
}

CLASTRACE_TARGET_AVX2 inline unsigned le_lanes8(__m256 a, __m256 b) {
    return unsigned(_mm256_movemask_ps(_mm256_cmp_ps(a, b, _CMP_LE_OQ)));
}

// The eight floats `offset` bytes from a node's lo[0] (a plane of the node).
CLASTRACE_TARGET_AVX2 inline __m256 plane8(const WideNode8& n, int offset) {
    return _mm256_load_ps(
        reinterpret_cast<const float*>(reinterpret_cast<const char*>(&n.lo[0][0]) + offset));
}

// wide_hits for eight children at once: the same bounds, the same widening, so the same
// conservative answer for every box. Unused lanes (lo = +inf, hi = -inf) enter at +inf and
// leave at -inf, or fail the zero-axis test: never hit. kGeneral: any usable ray; false: a ray
// with no direction component exactly 0 and r.tmin >= 0 (walk_wide), for which the per-axis
// check drops out and the entry's widening takes one multiply (below).
template <bool kGeneral>
CLASTRACE_TARGET_AVX2 inline unsigned wide8_hits(const WideRay8& r, const WideNode8& n, float tmax,
                                                 float entry[8]) {
    __m256 near_t = _mm256_set1_ps(-__builtin_inff()), far_t = _mm256_set1_ps(__builtin_inff());
    unsigned inside = 0xFF;
    // Unrolled: the loop's own counting was 15 instructions a node (callgrind).
#pragma GCC unroll 3
    for (int a = 0; a < 3; ++a) {
        if (kGeneral && r.zero[a]) {
            inside &= le_lanes8(_mm256_load_ps(n.lo[a]), r.origin_above[a]) &
                      le_lanes8(r.origin_below[a], _mm256_load_ps(n.hi[a]));
            continue;
        }
        const __m256 t_near =
            _mm256_mul_ps(_mm256_sub_ps(plane8(n, r.near_plane[a]), r.origin[a]), r.inverse[a]);
        const __m256 t_far =
            _mm256_mul_ps(_mm256_sub_ps(plane8(n, r.far_plane[a]), r.origin[a]), r.inverse[a]);
        // Without zero axes the first axis's distances start the running max and min (against
        // -inf and +inf the max and min give them unchanged, NaN included; 4 instructions a
        // node).
        near_t = !kGeneral && a == 0 ? t_near : _mm256_max_ps(near_t, t_near);
        far_t = !kGeneral && a == 0 ? t_far : _mm256_min_ps(far_t, t_far);
    }
    if constexpr (kGeneral) {
        near_t = _mm256_sub_ps(_mm256_min_ps(_mm256_mul_ps(near_t, r.widen_down),
                                             _mm256_mul_ps(near_t, r.widen_up)),
                               r.widen_abs);
    } else {
        // With tmin >= 0 the general form's max(min(near wd, near wu) - wa, tmin) is
        // max(near wd - wa, tmin), bit for bit: for near >= 0 the smaller product is near wd
        // (rounding is monotone); for near < 0 (or NaN, -inf) both forms are below tmin (or
        // NaN) and the max gives tmin. One multiply and a min less on the visit's chain.
        near_t = _mm256_sub_ps(_mm256_mul_ps(near_t, r.widen_down), r.widen_abs);
    }
    far_t = _mm256_add_ps(_mm256_max_ps(_mm256_mul_ps(far_t, r.widen_down),
                                        _mm256_mul_ps(far_t, r.widen_up)),
                          r.widen_abs);
    near_t = _mm256_max_ps(near_t, r.tmin);
    far_t = _mm256_min_ps(far_t, _mm256_set1_ps(tmax));
    _mm256_storeu_ps(entry, near_t);
    return le_lanes8(near_t, far_t) & inside;
}

// wide8_hits as walk_nodes' box test: a class rather than a lambda, so that its call operator
// carries the AVX2 target attribute too.
template <bool kGeneral>
struct Wide8BoxTest {
    const WideRay8& ray;
    CLASTRACE_TARGET_AVX2 unsigned operator()(const WideNode8& n, float tmax, float* entry) const {
        return wide8_hits<kGeneral>(ray, n, tmax, entry);
    }
};

// A leaf of the AVX2 walk, out of line but compiled for AVX2 too (the leaf's code inlines
// here). Inlined into the walk, the leaf's registers left it short: GCC kept the entry visited
// next in the walk's frame, each child stored there and loaded back before its node could be
// read. Out of line it costs instructions (the call) but not that: on the device (Sapphire
// Rapids) the float32 walk ran 30% faster, the double one unchanged (benchmarks.md, round 16).
template <class Leaf>
[[gnu::noinline]] CLASTRACE_TARGET_AVX2 bool wide8_leaf(Leaf& leaf, uint32_t first,
                                                        uint32_t count) {
    return leaf(first, count);
}

// walk_nodes over 8-wide float nodes with the AVX2 box test.
template <bool kGeneral, class Leaf, class Prefetch>
CLASTRACE_TARGET_AVX2 void walk_wide8_nodes(const HugePageVector<WideNode8>& nodes,
                                            const WideRay& wide_ray, double* tmax, Leaf& leaf,
                                            Prefetch& prefetch) {
    const WideRay8 r = make_wide_ray8(wide_ray);
    auto out_of_line = [&leaf](uint32_t first, uint32_t count) {
        return wide8_leaf(leaf, first, count);
    };
    walk_nodes<8>(nodes, Wide8BoxTest<kGeneral>{r}, tmax, out_of_line, prefetch);
}
#endif

template <class Leaf, class Prefetch>
void walk_wide(const WideTree& tree, const WideRay& r, double* tmax, Leaf&& leaf,
               Prefetch&& prefetch) {
    const bool zero_axes = r.zero[0] || r.zero[1] || r.zero[2];
#if defined(CLASTRACE_AVX2_PATH)
    if (!tree.nodes8.empty()) {
        // (`!(tmin >= 0)`: NaN too, though a usable ray's tmin is not NaN.)
        if (zero_axes || !(r.tmin >= 0.0f))
            walk_wide8_nodes<true>(tree.nodes8, r, tmax, leaf, prefetch);
        else
            walk_wide8_nodes<false>(tree.nodes8, r, tmax, leaf, prefetch);
        return;
    }
#endif
    if (!tree.quantized.empty()) {
        if (zero_axes)
            walk_wide_nodes<true>(tree.quantized, r, tmax, leaf, prefetch);
        else
            walk_wide_nodes<false>(tree.quantized, r, tmax, leaf, prefetch);
    } else {
        if (zero_axes)
            walk_wide_nodes<true>(tree.nodes, r, tmax, leaf, prefetch);
        else
            walk_wide_nodes<false>(tree.nodes, r, tmax, leaf, prefetch);
    }
}

}  // namespace clastrace::engine::detail
