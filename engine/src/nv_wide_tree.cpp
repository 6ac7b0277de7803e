// SPDX-License-Identifier: Apache-2.0
// Collapsing a stored NV tree into the traversal's 8- or 4-wide layout, the choice between
// them (SimdPath), and the SIMD box test's ray with its error bounds (nv_wide_tree.h).
#include "nv_wide_tree.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <limits>

namespace clastrace::engine::detail {
namespace {

bool has_nan(const NvNode& n) {
    for (int a = 0; a < 3; ++a)
        if (std::isnan(n.bounds_min[a]) || std::isnan(n.bounds_max[a])) return true;
    return false;
}

double half_area(const NvNode& n) {
    const double dx = double(n.bounds_max[0]) - n.bounds_min[0],
                 dy = double(n.bounds_max[1]) - n.bounds_min[1],
                 dz = double(n.bounds_max[2]) - n.bounds_min[2];
    return dx * dy + dy * dz + dz * dx;
}

// The records under each stored node: [first, first + count) when its leaves cover exactly
// that range, each once, and no box in the subtree has a NaN bound; count 0 otherwise.
struct RecordSpan {
    uint32_t first = 0, count = 0;
};

std::vector<RecordSpan> record_spans(const std::vector<NvNode>& nodes) {
    std::vector<RecordSpan> spans(nodes.size());
    // Children come after their parent (open_nv_object's rule): one pass from the back.
    for (size_t i = nodes.size(); i-- > 0;) {
        const NvNode& n = nodes[i];
        if (has_nan(n)) continue;
        if (n.count != 0) {
            spans[i] = RecordSpan{n.first, n.count};
            continue;
        }
        const RecordSpan l = spans[i + 1], r = spans[n.first];
        if (l.count == 0 || r.count == 0) continue;
        const uint64_t lo = std::min(l.first, r.first);
        const uint64_t hi = std::max(uint64_t(l.first) + l.count, uint64_t(r.first) + r.count);
        // Disjoint and adjacent exactly when the union is as long as the two together.
        if (hi - lo == uint64_t(l.count) + r.count)
            spans[i] = RecordSpan{uint32_t(lo), l.count + r.count};
    }
    return spans;
}

// A stored subtree of at most this many records, contiguous, becomes one leaf lane (three
// groups of four triangles at most): the builder's leaves hold 1-2 triangles, and on the
// device a level of nodes less (each a load that misses, on the walk's chain) gained more than
// the extra triangle tests cost: 4 -> 8 -> 12 records, +12% -> +16% (benchmarks.md, round 17).
constexpr uint32_t kMergedLeafRecords = 12;

bool is_leaf(const NvNode& n, const RecordSpan& span) {
    return n.count != 0 || (span.count != 0 && span.count <= kMergedLeafRecords);
}

// The stored nodes one wide node of `width` lanes holds: starting from `slots`, the inner node
// with the largest box is replaced by its children until `width` are held or only leaves are
// left, as wide BVHs are commonly collapsed (the large boxes are the ones most rays enter).
std::vector<uint32_t> collapse(const std::vector<NvNode>& nodes,
                               const std::vector<RecordSpan>& spans, std::vector<uint32_t> slots,
                               size_t width) {
    while (slots.size() < width) {
        int widest = -1;
        double widest_area = 0.0;
        for (size_t k = 0; k < slots.size(); ++k) {
            const NvNode& n = nodes[slots[k]];
            if (is_leaf(n, spans[slots[k]])) continue;
            const double area = half_area(n);
            if (widest < 0 || area > widest_area) {
                widest = int(k);
                widest_area = area;
            }
        }
        if (widest < 0) break;
        const uint32_t inner = slots[size_t(widest)];
        slots.erase(slots.begin() + widest);
        for (const uint32_t c : {inner + 1, nodes[inner].first})
            if (!has_nan(nodes[c])) slots.push_back(c);
    }
    return slots;
}

// The root's center and the leaves' mean largest extent (WideTree, resolves_leaves). A root
// that is not finite (a single-BLAS scene's top level) leaves them NaN: the float walk.
template <int W>
void set_scale(const NvNode& root, const std::vector<FloatWideNode<W>>& nodes, WideTree* tree) {
    for (int a = 0; a < 3; ++a)
        tree->center[a] = (double(root.bounds_min[a]) + double(root.bounds_max[a])) * 0.5;
    double sum = 0.0;
    size_t leaves = 0;
    for (const FloatWideNode<W>& w : nodes)
        for (int k = 0; k < W; ++k) {
            if (w.count[k] == kWideEmptyLane || w.count[k] == 0) continue;
            double extent = 0.0;
            for (int a = 0; a < 3; ++a)
                extent = std::max(extent, double(w.hi[a][k]) - double(w.lo[a][k]));
            sum += extent;
            ++leaves;
        }
    tree->leaf_extent = leaves ? sum / double(leaves) : 0.0;
    if (!std::isfinite(tree->leaf_extent))
        tree->leaf_extent = std::numeric_limits<double>::quiet_NaN();
}

// The smallest exponent e in [-126, 127] with 255 * 2^e >= extent (extent finite, >= 0).
int8_t step_exponent(double extent) {
    int e = -126;
    if (extent > 255.0 * std::ldexp(1.0, e)) {
        std::frexp(extent / 255.0, &e);  // extent / 255 < 2^e
        while (e > -126 && 255.0 * std::ldexp(1.0, e - 1) >= extent) --e;
        while (255.0 * std::ldexp(1.0, e) < extent) ++e;
    }
    return int8_t(e);
}

// `w` quantized, or false when a frame bound is not finite or a leaf is too long. Each byte
// starts at the nearest outward step and moves outward until the traversal's own
// dequantization (dequantized) contains the stored bound. A lane's box is taken as the hull of
// its two bounds (the same box the min/max slab test sees of an inverted one), so that qlo <=
// qhi, which the 8-wide test's choice of planes by the ray's signs relies on.
bool quantize_node(const WideNode& w, QuantizedWideNode* q) {
    constexpr int W = 4;
    *q = QuantizedWideNode{};
    unsigned used = 0;
    for (int k = 0; k < W; ++k) {
        q->child[k] = w.child[k];
        q->count[k] = kQuantizedEmptyLane;
        if (w.count[k] == kWideEmptyLane) continue;
        if (w.count[k] > kQuantizedMaxLeaf) return false;
        q->count[k] = uint8_t(w.count[k]);
        used |= 1u << k;
    }
    q->used = uint8_t(used);
    for (int a = 0; a < 3; ++a) {
        float box_lo[W], box_hi[W];
        float lo = std::numeric_limits<float>::infinity(), hi = -lo;
        for (int k = 0; k < W; ++k) {
            box_lo[k] = std::min(w.lo[a][k], w.hi[a][k]);
            box_hi[k] = std::max(w.lo[a][k], w.hi[a][k]);
            if (!(used >> k & 1)) continue;
            lo = std::min(lo, box_lo[k]);
            hi = std::max(hi, box_hi[k]);
        }
        if (used == 0) lo = hi = 0.0f;
        if (!std::isfinite(lo) || !std::isfinite(hi)) return false;
        q->origin[a] = lo;
        q->exponent[a] = step_exponent(double(hi) - double(lo));
        const double step = std::ldexp(1.0, q->exponent[a]);
        for (int k = 0; k < W; ++k) {
            if (!(used >> k & 1)) continue;
            const double qlo = std::floor((double(box_lo[k]) - lo) / step);
            const double qhi = std::ceil((double(box_hi[k]) - lo) / step);
            q->qlo[a][k] = uint8_t(std::clamp(qlo, 0.0, 255.0));
            q->qhi[a][k] = uint8_t(std::clamp(qhi, 0.0, 255.0));
            while (!(dequantized(q->origin[a], q->qlo[a][k], q->exponent[a]) <= box_lo[k])) {
                if (q->qlo[a][k] == 0) return false;
                --q->qlo[a][k];
            }
            while (!(dequantized(q->origin[a], q->qhi[a][k], q->exponent[a]) >= box_hi[k])) {
                if (q->qhi[a][k] == 255) return false;
                ++q->qhi[a][k];
            }
        }
    }
    return true;
}

// The quantized form of every node, or nothing when one cannot be quantized.
HugePageVector<QuantizedWideNode> quantize_tree(const HugePageVector<WideNode>& nodes) {
    HugePageVector<QuantizedWideNode> out(nodes.size());
    for (size_t i = 0; i < nodes.size(); ++i)
        if (!quantize_node(nodes[i], &out[i])) return {};
    return out;
}

// The tree collapsed into nodes of W lanes with float boxes (make_float_wide_tree).
template <int W>
std::vector<FloatWideNode<W>> float_wide_nodes(const std::vector<NvNode>& nodes) {
    std::vector<FloatWideNode<W>> out;
    if (nodes.empty() || has_nan(nodes[0])) return out;
    struct Pending {
        uint32_t wide;
        std::vector<uint32_t> slots;
    };
    const std::vector<RecordSpan> spans = record_spans(nodes);
    std::vector<Pending> pending{{0, {0}}};
    out.emplace_back();
    while (!pending.empty()) {
        Pending p = std::move(pending.back());
        pending.pop_back();
        const std::vector<uint32_t> slots = collapse(nodes, spans, std::move(p.slots), W);
        FloatWideNode<W> w{};
        for (int k = 0; k < W; ++k) {
            w.count[k] = kWideEmptyLane;
            if (size_t(k) >= slots.size()) continue;
            const NvNode& n = nodes[slots[size_t(k)]];
            for (int a = 0; a < 3; ++a) {
                w.lo[a][k] = n.bounds_min[a];
                w.hi[a][k] = n.bounds_max[a];
            }
            const RecordSpan& span = spans[slots[size_t(k)]];
            if (is_leaf(n, span)) {
                w.child[k] = n.count != 0 ? n.first : span.first;
                w.count[k] = n.count != 0 ? n.count : span.count;
                continue;
            }
            std::vector<uint32_t> children;
            const uint32_t inner = slots[size_t(k)];
            for (const uint32_t c : {inner + 1, n.first})
                if (!has_nan(nodes[c])) children.push_back(c);
            w.child[k] = uint32_t(out.size());
            w.count[k] = 0;
            out.emplace_back();
            pending.push_back(Pending{w.child[k], std::move(children)});
        }
        out[p.wide] = w;
    }
    return out;
}

// An 8-wide node as the AVX2 box test takes it (WideNode8): each used lane's box the hull of
// its bounds, each unused lane's lo = +inf and hi = -inf.
void close_lanes(WideNode8* n) {
    const float inf = std::numeric_limits<float>::infinity();
    for (int k = 0; k < 8; ++k)
        for (int a = 0; a < 3; ++a) {
            const bool used = n->count[k] != kWideEmptyLane;
            const float lo = n->lo[a][k], hi = n->hi[a][k];
            n->lo[a][k] = used ? std::min(lo, hi) : inf;
            n->hi[a][k] = used ? std::max(lo, hi) : -inf;
        }
}

// The process's path: 0 not yet decided, else 1 + SimdPath.
std::atomic<int> forced_path{0};

}  // namespace

bool cpu_has_avx2() {
#if defined(CLASTRACE_AVX2_PATH)
    static const bool has = __builtin_cpu_supports("avx2");
    return has;
#else
    return false;
#endif
}

SimdPath active_simd_path() {
    const int forced = forced_path.load(std::memory_order_relaxed);
    if (forced != 0) return SimdPath(forced - 1);
    static const SimdPath chosen = [] {
        const char* env = std::getenv("CLASTRACE_ENGINE_SIMD");
        if (env && std::strcmp(env, "sse") == 0) return SimdPath::kSse;
        return cpu_has_avx2() ? SimdPath::kAvx2 : SimdPath::kSse;
    }();
    return chosen;
}

void force_simd_path(std::optional<SimdPath> path) {
    if (path == SimdPath::kAvx2 && !cpu_has_avx2()) path = SimdPath::kSse;
    forced_path.store(path ? 1 + int(*path) : 0, std::memory_order_relaxed);
}

WideTree make_wide_tree(const std::vector<NvNode>& nodes, SimdPath path) {
    if (path == SimdPath::kAvx2 && cpu_has_avx2()) {
        const std::vector<WideNode8> wide = float_wide_nodes<8>(nodes);
        WideTree tree;
        if (!wide.empty()) set_scale(nodes[0], wide, &tree);
        tree.nodes8.assign(wide.begin(), wide.end());
        for (WideNode8& n : tree.nodes8) close_lanes(&n);
        return tree;
    }
    WideTree tree = make_float_wide_tree(nodes);
    tree.quantized = quantize_tree(tree.nodes);
    if (!tree.quantized.empty()) tree.nodes = {};
    return tree;
}

WideTree make_float_wide_tree(const std::vector<NvNode>& nodes) {
    WideTree tree;
    const std::vector<FloatWideNode<4>> wide = float_wide_nodes<4>(nodes);
    tree.nodes.assign(wide.begin(), wide.end());
    if (!wide.empty()) set_scale(nodes[0], wide, &tree);
    return tree;
}

std::vector<WideNode8> make_float_wide_nodes8(const std::vector<NvNode>& nodes) {
    return float_wide_nodes<8>(nodes);
}

namespace {

// The groups of records [first, first + count), appended to `groups`.
void append_groups(const std::vector<NvPrimitiveRecord>& records, uint32_t first, uint32_t count,
                   HugePageVector<geometry::Triangle4>* groups) {
    for (uint32_t g = 0; g < count; g += 4) {
        geometry::Triangle4 t{};
        for (uint32_t k = 0; k < 4; ++k) {
            const uint64_t index = uint64_t(first) + g + k;
            t.geometry[k] = t.primitive[k] = geometry::kNoTriangle;
            if (g + k >= count || index >= records.size()) continue;
            const NvPrimitiveRecord& r = records[index];
            for (int c = 0; c < 9; ++c) t.v[c][k] = r.v[c];
            t.geometry[k] = r.geometry_index;
            t.primitive[k] = r.primitive_index;
        }
        groups->push_back(t);
    }
}

// The groups the leaves of `nodes` need, so that the array is allocated once, at its size.
template <class Node>
size_t count_groups(const HugePageVector<Node>& nodes) {
    constexpr int kLanes = int(sizeof(Node::child) / sizeof(uint32_t));
    size_t groups = 0;
    for (const Node& n : nodes)
        for (int k = 0; k < kLanes; ++k) {
            const uint32_t count = lane_count(n, k);
            if (count != 0 && count != kWideEmptyLane) groups += (count + 3) / 4;
        }
    return groups;
}

template <class Node>
void group_leaves(HugePageVector<Node>* nodes, const std::vector<NvPrimitiveRecord>& records,
                  HugePageVector<geometry::Triangle4>* groups) {
    constexpr int kLanes = int(sizeof(Node::child) / sizeof(uint32_t));
    for (Node& n : *nodes)
        for (int k = 0; k < kLanes; ++k) {
            const uint32_t count = lane_count(n, k);
            if (count == 0 || count == kWideEmptyLane) continue;
            const uint32_t first = n.child[k];
            n.child[k] = uint32_t(groups->size());
            append_groups(records, first, count, groups);
        }
}

}  // namespace

HugePageVector<geometry::Triangle4> group_leaf_triangles(
    WideTree* tree, const std::vector<NvPrimitiveRecord>& records) {
    HugePageVector<geometry::Triangle4> groups;
    groups.reserve(count_groups(tree->nodes) + count_groups(tree->quantized) +
                   count_groups(tree->nodes8));
    group_leaves(&tree->nodes, records, &groups);
    group_leaves(&tree->quantized, records, &groups);
    group_leaves(&tree->nodes8, records, &groups);
    tree->leaf_groups = true;
    return groups;
}

namespace {

float float_at_or_below(double t) {
    float f = float(t);
    if (double(f) > t) f = std::nextafter(f, -std::numeric_limits<float>::infinity());
    return f;
}

// Each lane's distance is fl(fl(lo - o_f) * fl(1 / d)) with o_f the origin rounded to float.
// With delta = o - o_f (exact in double) that is (lo - o + delta) / d times three roundings,
// so the exact distance (lo - o) / d lies within gamma(3) / (1 - gamma(3)) of the float
// distance relative, plus |delta| |1/d| absolute. The widening below covers the relative
// part with 2^-20 (> 5 gamma(3)) and the absolute part with |delta| |1/d| (1 + 2^-20), zero
// when the origin is a float already (every float32-mode ray, and world rays through identity
// instances); 2^-120 covers products that underflow. Bounding the absolute part by the
// origin's magnitude instead (u |o| |1/d|) widened rays from far away, or with a direction
// component near 0, across whole scenes. The range limits keep every term finite and normal.
//
// TraversalMode::kFloat32 rays hold their origin and 1 / d as floats already (fo, finv): their
// lane distances are then bit for bit those of the scalar float32 test (slab_test_float32,
// which widens them by 4 float epsilons in double), and widening by 5 epsilons in float (each
// product rounds by at most half an epsilon) keeps every box that test keeps.
constexpr double kRelativeWidening = 0x1p-20;
constexpr double kFloat32RelativeWidening = 5.0 * std::numeric_limits<float>::epsilon();
constexpr double kUnderflowWidening = 0x1p-120;
constexpr double kRangeLimit = 0x1p100;

}  // namespace

WideRay4 make_wide_ray4(const WideRay& r) {
    WideRay4 w;
    for (int a = 0; a < 3; ++a) {
        w.zero[a] = r.zero[a];
        w.origin[a] = splat(r.origin[a]);
        w.inverse[a] = splat(r.inverse[a]);
        w.origin_below[a] = r.origin_below[a];
        w.origin_above[a] = r.origin_above[a];
    }
    w.widen_down = splat(r.widen_down);
    w.widen_up = splat(r.widen_up);
    w.widen_abs = splat(r.widen_abs);
    w.tmin = splat(r.tmin);
    return w;
}

WideRay make_wide_ray(const geometry::PreparedRay& r) {
    WideRay w;
    if (std::isnan(r.tmin)) return w;
    const bool float32 = r.mode == TraversalMode::kFloat32;
    double abs_term = 0.0;
    for (int a = 0; a < 3; ++a) {
        const double o = r.o[a], d = r.d[a];
        if (!(std::fabs(o) <= kRangeLimit)) return w;  // also NaN and inf
        w.origin[a] = float(o);
        w.zero[a] = d == 0.0;
        if (w.zero[a]) {
            // Only zero axes read these (wide_hits).
            w.origin_below[a] = float_at_or_below(o);
            w.origin_above[a] = float_at_or_above(o);
            w.inverse[a] = 0.0f;
            continue;
        }
        const double inv = float32 ? double(r.finv[a]) : r.inv[a];
        if (!(std::fabs(inv) <= kRangeLimit && std::fabs(inv) >= 1.0 / kRangeLimit)) return w;
        w.inverse[a] = float(inv);
        abs_term = std::max(abs_term, std::fabs(o - double(float(o))) * std::fabs(inv));
    }
    const double widening = float32 ? kFloat32RelativeWidening : kRelativeWidening;
    w.widen_down = float(1.0 - widening);
    w.widen_up = float(1.0 + widening);
    w.widen_abs = float_at_or_above(abs_term * (1.0 + kRelativeWidening) + kUnderflowWidening);
    w.tmin = float_at_or_below(r.tmin);
    w.usable = true;
    return w;
}

namespace {

// make_plain_object_rays for one mode (a template: a test of the mode in the loop cost the
// double mode 15 instructions a ray).
template <bool kFloat32>
bool plain_object_rays(const float o[3], const float d[3], double tmin, double tmax,
                       ObjectRays* out) {
    if (std::isnan(tmin)) return false;
    // The wide ray's range on every axis, four lanes at once (lane 3: o = d = 0, left out):
    // |o| <= 2^100, and 2^-100 <= |d| <= 2^100, which for a float d is exactly 1 / d in
    // double within [2^-100, 2^100] (the bounds are powers of two and 1 / d rounds
    // monotonically; the floats next to them invert past them); NaN fails each test. (Per
    // axis and on 1 / d, the checks were a third of this function.)
    static_assert(kRangeLimit == 0x1p100);
    const Float4 abs_o = abs4(load3(o)), abs_d = abs4(load3(d));
    const unsigned in_range = le_lanes(abs_o, splat(0x1p100f)) & le_lanes(splat(0x1p-100f), abs_d) &
                              le_lanes(abs_d, splat(0x1p100f));
    if ((in_range & 7u) != 7u) return false;
    geometry::PreparedRay& r = out->exact;
    WideRay& w = out->wide;
#pragma GCC unroll 3
    for (int a = 0; a < 3; ++a) {
        r.o[a] = double(o[a]) + 0.0;  // -0 as +0, as an identity's rows give it
        r.d[a] = d[a];
        r.inv[a] = 1.0 / r.d[a];
        r.fo[a] = float(r.o[a]);
        w.zero[a] = false;
        w.origin[a] = r.fo[a];
        if constexpr (kFloat32) {
            // A float32 pipeline's own 1 / d (rounded once, from the float: not float(inv)).
            r.fd[a] = d[a];
            r.finv[a] = 1.0f / d[a];
            w.inverse[a] = r.finv[a];
        } else {
            w.inverse[a] = float(r.inv[a]);
        }
    }
    // prepare_ray's permutation and shear.
    int kz = 0;
    if (std::fabs(r.d[1]) > std::fabs(r.d[kz])) kz = 1;
    if (std::fabs(r.d[2]) > std::fabs(r.d[kz])) kz = 2;
    static constexpr int kNext[3] = {1, 2, 0};
    int kx = kNext[kz], ky = kNext[kx];
    if (r.d[kz] < 0.0) std::swap(kx, ky);
    r.kx = kx;
    r.ky = ky;
    r.kz = kz;
    r.sx = r.d[kx] / r.d[kz];
    r.sy = r.d[ky] / r.d[kz];
    r.sz = 1.0 / r.d[kz];
    r.fsx = d[kx] / d[kz];
    r.fsy = d[ky] / d[kz];
    r.fsz = 1.0f / d[kz];
    r.tmin = tmin;
    r.tmax = tmax;
    r.mode = kFloat32 ? TraversalMode::kFloat32 : TraversalMode::kDouble;
    // make_triangle4_ray's limits (its origin's rounding is 0: the origin is a float).
    const double dz = std::fabs(r.d[kz]);
    if (!(dz >= 0x1p-100 && dz <= 0x1p100)) return false;
    if (!(std::fabs(r.fsx) <= 1.0f + 0x1p-10f && std::fabs(r.fsy) <= 1.0f + 0x1p-10f)) return false;
    geometry::Triangle4Ray& t = out->triangles;
    for (int a = 0; a < 3; ++a) t.origin[a] = splat(r.fo[a]);
    t.kx = kx;
    t.ky = ky;
    t.kz = kz;
    t.sx = splat(r.fsx);
    t.sy = splat(r.fsy);
    t.sz = splat(r.fsz);
    t.abs_sz = splat(float(std::fabs(double(r.fsz)) * (1.0 + 0x1p-20)));
    t.delta2 = splat(0.0f);
    t.delta4 = splat(0.0f);
    t.usable = true;
    // make_wide_ray's widening with no origin rounding: the underflow term alone.
    const double widening = kFloat32 ? kFloat32RelativeWidening : kRelativeWidening;
    w.widen_down = float(1.0 - widening);
    w.widen_up = float(1.0 + widening);
    w.widen_abs = float(kUnderflowWidening);
    w.tmin = float_at_or_below(tmin);
    w.usable = true;
    return true;
}

}  // namespace

bool make_plain_object_rays(const float o[3], const float d[3], double tmin, double tmax,
                            TraversalMode mode, ObjectRays* out) {
    return mode == TraversalMode::kFloat32 ? plain_object_rays<true>(o, d, tmin, tmax, out)
                                           : plain_object_rays<false>(o, d, tmin, tmax, out);
}

}  // namespace clastrace::engine::detail
