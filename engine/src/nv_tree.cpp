// SPDX-License-Identifier: Apache-2.0
// Binned SAH over primitive or instance boxes (the engine's SAH core,
// geometry/binned_sah.h, chooses the splits): each box is copied once into a 32-byte
// BoxRef (box + item id), every node bins its range in one pass (32 bins x 3 axes, SSE),
// and the chosen split partitions the BoxRefs in place while gathering both children's
// box and centroid bounds, so no pass recomputes them; ranges of up to 16 items take the
// exact sweep over their centroid order instead of bins. Object-median fallback when the
// centroids coincide or past depth 64. Split costs are
// evaluated in double so huge boxes (coordinates near FLT_MAX) still compare; infinite
// areas never win a split. The core's top-down builder lays the nodes out in preorder;
// large ranges build their two halves as TBB tasks into their own node arrays, spliced in
// depth-first order: the tree depends only on the boxes, never on the thread count.
#include "nv_internal.h"

#include "geometry/binned_sah.h"

#include <emmintrin.h>
#include <tbb/global_control.h>
#include <tbb/parallel_invoke.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>

namespace clastrace::engine::nv {
namespace {

// Most bins per axis (ranges of n items use 4 + n / 20, at least 8); items and nodes cost
// alike.
constexpr geometry::SahParams kSah{32, 1.0, 1.0, kNvMaxLeafSize};
constexpr int kBins = kSah.max_bins;
// Ranges of up to this many items take the exact sweep instead of bins.
constexpr uint32_t kSweepItems = 16;
// Below this many items a subtree is built on the calling thread.
constexpr uint32_t kParallelItems = 16384;

// One item: lane 3 of lo holds the item id, lane 3 of hi is unused (never read as a float).
struct alignas(16) BoxRef {
    float lo[3];
    uint32_t id;
    float hi[3];
    uint32_t pad;
};
static_assert(sizeof(BoxRef) == 32);

// lo with the id lane zeroed: small ids read as float are denormals, which make every
// multiply on the lane take a slow microcode path.
__m128 load_lo(const BoxRef& r) {
    const __m128 xyz = _mm_castsi128_ps(_mm_set_epi32(0, -1, -1, -1));
    return _mm_and_ps(_mm_load_ps(r.lo), xyz);
}

struct Bounds4 {
    __m128 lo, hi;
    static Bounds4 empty() {
        return {_mm_set1_ps(std::numeric_limits<float>::infinity()),
                _mm_set1_ps(-std::numeric_limits<float>::infinity())};
    }
    // minps/maxps return their second operand when either is NaN: a NaN centroid is ignored.
    void grow(__m128 l, __m128 h) {
        lo = _mm_min_ps(l, lo);
        hi = _mm_max_ps(h, hi);
    }
    void grow(const Bounds4& b) { grow(b.lo, b.hi); }
};

float lane(__m128 v, int a) {
    alignas(16) float f[4];
    _mm_store_ps(f, v);
    return f[a];
}

double half_area(const Bounds4& b) {
    alignas(16) float lo[4], hi[4];
    _mm_store_ps(lo, b.lo);
    _mm_store_ps(hi, b.hi);
    if (!(lo[0] <= hi[0] && lo[1] <= hi[1] && lo[2] <= hi[2])) return 0.0;
    const double dx = double(hi[0]) - lo[0], dy = double(hi[1]) - lo[1], dz = double(hi[2]) - lo[2];
    return dx * dy + dy * dz + dz * dx;
}

// half_area of a non-empty box without the emptiness test, in double SIMD (the sweeps only
// ask for boxes of at least one item).
double sweep_area(const Bounds4& b) {
    const __m128d lo01 = _mm_cvtps_pd(b.lo), lo23 = _mm_cvtps_pd(_mm_movehl_ps(b.lo, b.lo));
    const __m128d hi01 = _mm_cvtps_pd(b.hi), hi23 = _mm_cvtps_pd(_mm_movehl_ps(b.hi, b.hi));
    const __m128d d01 = _mm_sub_pd(hi01, lo01), d23 = _mm_sub_pd(hi23, lo23);
    const double dx = _mm_cvtsd_f64(d01), dy = _mm_cvtsd_f64(_mm_unpackhi_pd(d01, d01)),
                 dz = _mm_cvtsd_f64(d23);
    return dx * dy + dy * dz + dz * dx;
}

// Halves first: lo + hi would overflow to inf for coordinates near FLT_MAX.
__m128 centroid(__m128 lo, __m128 hi) {
    const __m128 half = _mm_set1_ps(0.5f);
    return _mm_add_ps(_mm_mul_ps(lo, half), _mm_mul_ps(hi, half));
}

// A node's items [begin, end) with their box and centroid bounds.
struct Range {
    uint32_t begin = 0, end = 0;
    Bounds4 box, centroids;
    uint32_t count() const { return end - begin; }
};

// Bin index of a centroid per axis: c * scale - lo * scale (no overflow for huge
// extents), clamped to [0, kBins - 1]; NaN goes to bin 0 (maxps returns its second operand
// when the first is NaN), an unusable axis (scale 0) to bin 0.
struct BinMap {
    __m128 scale, offset;
    bool usable[3];
    int bins_used;
    BinMap(const Bounds4& c, int n) : bins_used(n) {
        alignas(16) float s[4] = {0, 0, 0, 0}, o[4] = {0, 0, 0, 0};
        for (int a = 0; a < 3; ++a) {
            const double lo = lane(c.lo, a), extent = double(lane(c.hi, a)) - lo;
            usable[a] = extent > 0.0 && std::isfinite(extent);
            if (!usable[a]) continue;
            // Slightly under kBins so the maximum centroid lands in the last bin, not past it.
            s[a] = float(n * (1.0 - 1e-6) / extent);
            o[a] = float(lo * s[a]);
        }
        scale = _mm_load_ps(s);
        offset = _mm_load_ps(o);
    }
    __m128i bins(__m128 c) const {
        __m128 x = _mm_sub_ps(_mm_mul_ps(c, scale), offset);
        x = _mm_max_ps(x, _mm_setzero_ps());
        x = _mm_min_ps(x, _mm_set1_ps(float(bins_used - 1)));
        return _mm_cvttps_epi32(x);
    }
};

using Split = geometry::SahSplit<double>;

// The node emitter: NvNode, an inner node naming its right child (the left one follows it).
struct NvNodeEmitter {
    using Node = NvNode;
    static void set_bounds(Node& n, const Bounds4& b) {
        alignas(16) float lo[4], hi[4];
        _mm_store_ps(lo, b.lo);
        _mm_store_ps(hi, b.hi);
        std::memcpy(n.bounds_min, lo, 12);
        std::memcpy(n.bounds_max, hi, 12);
    }
    void leaf(Node& n, const Range& r) const {
        set_bounds(n, r.box);
        n.first = r.begin;
        n.count = r.count();
    }
    void inner(Node& n, const Range& r) const {
        set_bounds(n, r.box);
        n.count = 0;
    }
    void link(Node& n, uint32_t right_child) const { n.first = right_child; }
    uint32_t linked(const Node& n) const { return n.first; }
    bool is_inner(const Node& n) const { return n.count == 0; }
};

// Chooses the SAH splits over the shared BoxRef array (leaf `first` indexes it).
struct SahSplitter {
    BoxRef* refs;

    Split find_split(const Range& r, const BinMap& map) const {
        const int bins = map.bins_used;
        Bounds4 bin_box[3][kBins];
        uint32_t bin_count[3][kBins];
        for (int a = 0; a < 3; ++a)
            for (int k = 0; k < bins; ++k) {
                bin_box[a][k] = Bounds4::empty();
                bin_count[a][k] = 0;
            }
        for (uint32_t i = r.begin; i < r.end; ++i) {
            const __m128 lo = load_lo(refs[i]), hi = _mm_load_ps(refs[i].hi);
            alignas(16) int32_t k[4];
            _mm_store_si128(reinterpret_cast<__m128i*>(k), map.bins(centroid(lo, hi)));
            for (int a = 0; a < 3; ++a) {
                bin_box[a][k[a]].grow(lo, hi);
                ++bin_count[a][k[a]];
            }
        }
        return geometry::cheapest_split<double, kBins>(
            bins, map.usable, [&](int a, int k) -> const Bounds4& { return bin_box[a][k]; },
            [&](int a, int k) { return bin_count[a][k]; }, Bounds4::empty(), sweep_area);
    }

    // Hoare partition of [begin, end) by the split (left: bin <= split.bin), gathering both
    // sides' bounds on the way.
    void partition(const Range& r, const BinMap& map, const Split& s, Range* left,
                   Range* right) const {
        Bounds4 lb = Bounds4::empty(), lc = Bounds4::empty(), rb = Bounds4::empty(),
                rc = Bounds4::empty();
        auto is_left = [&](const BoxRef& ref, __m128 c) {
            alignas(16) int32_t k[4];
            _mm_store_si128(reinterpret_cast<__m128i*>(k), map.bins(c));
            (void)ref;
            return k[s.axis] <= s.bin;
        };
        uint32_t i = r.begin, j = r.end;
        while (true) {
            while (i < j) {
                const __m128 lo = load_lo(refs[i]), hi = _mm_load_ps(refs[i].hi),
                             c = centroid(lo, hi);
                if (!is_left(refs[i], c)) break;
                lb.grow(lo, hi);
                lc.grow(c, c);
                ++i;
            }
            while (i < j) {
                const __m128 lo = load_lo(refs[j - 1]), hi = _mm_load_ps(refs[j - 1].hi),
                             c = centroid(lo, hi);
                if (is_left(refs[j - 1], c)) break;
                rb.grow(lo, hi);
                rc.grow(c, c);
                --j;
            }
            if (i >= j) break;
            std::swap(refs[i], refs[j - 1]);  // refs[i] is now a left item, refs[j - 1] a right one
        }
        *left = Range{r.begin, i, lb, lc};
        *right = Range{i, r.end, rb, rc};
    }

    // Splits at the middle of the current order; both halves' bounds from one pass each.
    void split_middle(const Range& r, Range* left, Range* right) const {
        const uint32_t mid = r.begin + r.count() / 2;
        *left = bounds_of(r.begin, mid);
        *right = bounds_of(mid, r.end);
    }

    Range bounds_of(uint32_t begin, uint32_t end) const {
        Range r{begin, end, Bounds4::empty(), Bounds4::empty()};
        for (uint32_t i = begin; i < end; ++i) {
            const __m128 lo = load_lo(refs[i]), hi = _mm_load_ps(refs[i].hi), c = centroid(lo, hi);
            r.box.grow(lo, hi);
            r.centroids.grow(c, c);
        }
        return r;
    }

    // The SAH's verdict: a range that fits a leaf stays one unless `best` splits it cheaper.
    static bool leaf_cheaper(const Range& r, const Split& best) {
        const uint32_t count = r.count();
        if (count > kSah.max_leaf_size) return false;
        if (best.axis < 0) return true;
        const double area = half_area(r.box);
        return !(kSah.traversal_cost * area + kSah.intersection_cost * best.cost <
                 kSah.intersection_cost * area * count);
    }

    // The exact SAH split of a small range: per usable axis the items in centroid order (NaN
    // first, ties in range order), every cut between two neighbours evaluated by the SAH core
    // as a sweep over one-item bins. Cheaper than 16-32 bins for these few items (no bins to
    // clear, n - 1 cuts to sweep instead of 15-31) and never worse: binning only merges cuts.
    bool split_sorted(const Range& r, int depth, Range* left, Range* right) const {
        const uint32_t n = r.count();
        BoxRef* items = refs + r.begin;
        bool usable[3];
        uint8_t order[3][kSweepItems];
        for (int a = 0; a < 3; ++a) {
            const double extent = double(lane(r.centroids.hi, a)) - lane(r.centroids.lo, a);
            usable[a] = extent > 0.0;  // false for coincident (or all-NaN) centroids
            if (usable[a]) sort_by_centroid(items, n, a, order[a]);
        }
        const Split best = geometry::cheapest_split<double, kSweepItems>(
            int(n), usable,
            [&](int a, int k) {
                const BoxRef& b = items[order[a][k]];
                return Bounds4{load_lo(b), _mm_load_ps(b.hi)};
            },
            [](int, int) { return 1u; }, Bounds4::empty(), sweep_area);
        if (leaf_cheaper(r, best)) return false;
        if (best.axis < 0 || depth >= 64) {
            split_middle(r, left, right);
            return true;
        }
        BoxRef sorted[kSweepItems];
        for (uint32_t k = 0; k < n; ++k) sorted[k] = items[order[best.axis][k]];
        std::copy(sorted, sorted + n, items);
        const uint32_t cut = r.begin + uint32_t(best.bin) + 1;
        *left = bounds_of(r.begin, cut);
        *right = bounds_of(cut, r.end);
        return true;
    }

    // Insertion sort of item positions by centroid on `axis` (stable; NaN sorts first).
    static void sort_by_centroid(const BoxRef* items, uint32_t n, int axis, uint8_t* order) {
        float key[kSweepItems];
        for (uint32_t k = 0; k < n; ++k) {
            const float c = 0.5f * items[k].lo[axis] + 0.5f * items[k].hi[axis];
            key[k] = c == c ? c : -std::numeric_limits<float>::infinity();
        }
        for (uint32_t k = 0; k < n; ++k) {
            uint32_t j = k;
            for (; j > 0 && key[order[j - 1]] > key[k]; --j) order[j] = order[j - 1];
            order[j] = uint8_t(k);
        }
    }

    // False for a leaf; otherwise the two children's ranges, the items reordered in place.
    bool split(const Range& r, int depth, Range* left, Range* right) const {
        const uint32_t count = r.count();
        if (count <= 1) return false;
        if (count <= kSweepItems) return split_sorted(r, depth, left, right);
        // Embree's bin count: clearing and sweeping 32 bins costs more than binning the items
        // of a range of a few hundred; the SAH cost of the trees rose by at most 0.6%.
        const BinMap map(r.centroids, int(std::clamp<uint32_t>(4 + count / 20, 8, kBins)));
        const Split best = find_split(r, map);
        if (leaf_cheaper(r, best)) return false;
        // Deep chains (e.g. exponentially spaced boxes) fall back to median splits so the
        // recursion stays shallow (depth <= 64 + log2 n).
        if (best.axis >= 0 && depth < 64)
            partition(r, map, best, left, right);
        else
            split_middle(r, left, right);  // centroids coincide: any split is as good
        if (left->count() == 0 || right->count() == 0) split_middle(r, left, right);
        return true;
    }
};

// Spreads the low 10 bits of x to every third bit.
uint32_t spread_bits(uint32_t x) {
    x &= 0x3ff;
    x = (x | (x << 16)) & 0x030000ff;
    x = (x | (x << 8)) & 0x0300f00f;
    x = (x | (x << 4)) & 0x030c30c3;
    x = (x | (x << 2)) & 0x09249249;
    return x;
}

// Linear BVH over Morton codes (Lauterbach et al. 2009): the items sorted by the 30-bit
// code of their centroid, every node split where its range's highest differing code bit
// flips. One sort and one pass per level, no cost evaluation: the fast-build mode.
struct MortonBuilder {
    const Box* boxes;
    const uint32_t* items;  // sorted by code
    const uint32_t* codes;  // sorted
    uint32_t parallel_items;

    // Appends the subtree of [begin, end) to `out` (root at out.size()); returns its bounds.
    Bounds4 build(std::vector<NvNode>& out, uint32_t begin, uint32_t end) const {
        const uint32_t node = uint32_t(out.size());
        out.emplace_back();
        const uint32_t count = end - begin;
        if (count <= kNvMaxLeafSize) {
            Bounds4 b = Bounds4::empty();
            for (uint32_t i = begin; i < end; ++i) {
                const Box& box = boxes[items[i]];
                b.grow(_mm_setr_ps(box.lo[0], box.lo[1], box.lo[2], 0.0f),
                       _mm_setr_ps(box.hi[0], box.hi[1], box.hi[2], 0.0f));
            }
            NvNodeEmitter::set_bounds(out[node], b);
            out[node].first = begin;
            out[node].count = count;
            return b;
        }
        const uint32_t diff = codes[begin] ^ codes[end - 1];
        uint32_t mid = begin + count / 2;  // equal codes: any split is as good
        if (diff != 0) {
            const uint32_t bit = 1u << (31 - __builtin_clz(diff));
            mid = uint32_t(std::partition_point(codes + begin, codes + end,
                                                [&](uint32_t c) { return !(c & bit); }) -
                           codes);
        }
        Bounds4 b;
        out[node].count = 0;
        if (count < parallel_items) {
            b = build(out, begin, mid);
            out[node].first = uint32_t(out.size());
            b.grow(build(out, mid, end));
        } else {
            std::vector<NvNode> left_nodes, right_nodes;
            Bounds4 lb, rb;
            tbb::parallel_invoke([&] { lb = build(left_nodes, begin, mid); },
                                 [&] { rb = build(right_nodes, mid, end); });
            geometry::splice_preorder(NvNodeEmitter{}, out, left_nodes);
            out[node].first = uint32_t(out.size());
            geometry::splice_preorder(NvNodeEmitter{}, out, right_nodes);
            b = lb;
            b.grow(rb);
        }
        NvNodeEmitter::set_bounds(out[node], b);
        return b;
    }
};

// Stable LSD radix sort of (code, item) pairs by code, 3 passes of 10 bits: equal codes
// keep item order, so the result depends only on the boxes.
void sort_by_code(std::vector<uint32_t>& codes, std::vector<uint32_t>& items) {
    const size_t n = codes.size();
    std::vector<uint32_t> codes2(n), items2(n);
    std::vector<uint32_t> histograms(3 * 1024, 0);  // all three digits counted in one pass
    for (size_t i = 0; i < n; ++i)
        for (int d = 0; d < 3; ++d) ++histograms[1024 * d + ((codes[i] >> (10 * d)) & 1023)];
    for (int d = 0; d < 3; ++d) {
        uint32_t* start = histograms.data() + 1024 * d;
        uint32_t sum = 0;
        for (int k = 0; k < 1024; ++k) {
            const uint32_t c = start[k];
            start[k] = sum;
            sum += c;
        }
        for (size_t i = 0; i < n; ++i) {
            const uint32_t at = start[(codes[i] >> (10 * d)) & 1023]++;
            codes2[at] = codes[i];
            items2[at] = items[i];
        }
        codes.swap(codes2);
        items.swap(items2);
    }
}

}  // namespace

Box triangle_box(const float v[9]) {
    Box b = Box::empty();
    for (int k = 0; k < 3; ++k) b.grow_point(v + 3 * k);
    return b;
}

Box transform_box(const Box& local, const float m[12]) {
    Box out = Box::empty();
    for (int c = 0; c < 8; ++c) {
        const double p[3] = {(c & 1) ? local.hi[0] : local.lo[0],
                             (c & 2) ? local.hi[1] : local.lo[1],
                             (c & 4) ? local.hi[2] : local.lo[2]};
        for (int r = 0; r < 3; ++r) {
            const double w =
                m[4 * r] * p[0] + m[4 * r + 1] * p[1] + m[4 * r + 2] * p[2] + m[4 * r + 3];
            // Round outwards so the float box contains the exact one.
            const float f = float(w);
            const float lo =
                double(f) > w ? std::nextafter(f, -std::numeric_limits<float>::infinity()) : f;
            const float hi =
                double(f) < w ? std::nextafter(f, std::numeric_limits<float>::infinity()) : f;
            out.lo[r] = std::min(out.lo[r], lo);
            out.hi[r] = std::max(out.hi[r], hi);
        }
    }
    return out;
}

Tree build_tree(std::span<const Box> boxes, TreeQuality quality) {
    Tree t;
    if (boxes.empty()) return t;
    // One thread: no tasks and no splicing (the same bytes either way).
    // (global_control caps the threads without changing the arena's reported concurrency.)
    const size_t threads = std::min<size_t>(size_t(tbb::this_task_arena::max_concurrency()),
                                            tbb::global_control::active_value(
                                                tbb::global_control::max_allowed_parallelism));
    const uint32_t parallel_items = threads > 1 ? kParallelItems : ~0u;
    const uint32_t n = uint32_t(boxes.size());
    auto load = [&](uint32_t i, __m128* lo, __m128* hi) {
        *lo = _mm_setr_ps(boxes[i].lo[0], boxes[i].lo[1], boxes[i].lo[2], 0.0f);
        *hi = _mm_setr_ps(boxes[i].hi[0], boxes[i].hi[1], boxes[i].hi[2], 0.0f);
    };
    if (quality == TreeQuality::kSah) {
        std::vector<BoxRef> refs(n);
        for (uint32_t i = 0; i < n; ++i) {
            BoxRef& r = refs[i];
            std::memcpy(r.lo, boxes[i].lo, 12);
            std::memcpy(r.hi, boxes[i].hi, 12);
            r.id = i;
            r.pad = 0;
        }
        const SahSplitter splitter{refs.data()};
        t.nodes.reserve(2 * size_t(n));
        geometry::TopDownBuilder<geometry::NodeLayout::kPreorder, Range, SahSplitter,
                                 NvNodeEmitter>(splitter, NvNodeEmitter{}, parallel_items)
            .append(t.nodes, splitter.bounds_of(0, n), 0);
        t.order.resize(n);
        for (uint32_t i = 0; i < n; ++i) t.order[i] = refs[i].id;
        return t;
    }
    // Morton: no box copies; the codes and the sorted item order are all it keeps.
    Bounds4 centroids = Bounds4::empty();
    for (uint32_t i = 0; i < n; ++i) {
        __m128 lo, hi;
        load(i, &lo, &hi);
        const __m128 c = centroid(lo, hi);
        centroids.grow(c, c);
    }
    // 10 bits per axis over the centroid bounds (NaN and unusable axes quantize to 0).
    const BinMap map(centroids, 1024);
    std::vector<uint32_t> codes(n), items(n);
    for (uint32_t i = 0; i < n; ++i) {
        __m128 lo, hi;
        load(i, &lo, &hi);
        alignas(16) int32_t q[4];
        _mm_store_si128(reinterpret_cast<__m128i*>(q), map.bins(centroid(lo, hi)));
        codes[i] = spread_bits(uint32_t(q[0])) | spread_bits(uint32_t(q[1])) << 1 |
                   spread_bits(uint32_t(q[2])) << 2;
        items[i] = i;
    }
    t.nodes.reserve(size_t(n));  // leaves of up to 4 and Morton's uneven splits: about n nodes
    sort_by_code(codes, items);
    MortonBuilder{boxes.data(), items.data(), codes.data(), parallel_items}.build(t.nodes, 0, n);
    t.order = std::move(items);
    return t;
}

}  // namespace clastrace::engine::nv
