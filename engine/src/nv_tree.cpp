// SPDX-License-Identifier: Apache-2.0
// Binned SAH over primitive or instance boxes (the engine's SAH core,
// geometry/binned_sah.h, chooses the splits): each box is copied once into a 32-byte
// BoxRef (box + item id), every node bins its range in one pass (32 bins x 3 axes, SSE),
// and the chosen split partitions the BoxRefs in place while gathering both children's
// box and centroid bounds, so no pass recomputes them. Bottom levels end every range of up
// to four items as a leaf and bin every larger one (Embree's way); top levels let the SAH
// weigh small leaves and take the exact sweep over centroid order for ranges of up to 16
// items (TreeLevel). Object-median fallback when the centroids coincide or past depth 64.
// Split costs are evaluated in float for bottom-level ranges whose bounds lie within 2^40,
// in double elsewhere, so huge boxes (coordinates near FLT_MAX) still compare; infinite
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
#include <array>
#include <atomic>
#include <cmath>
#include <cstddef>
#include <cstring>
#include <limits>

namespace clastrace::engine::nv {
namespace {

// Most bins per axis (ranges of n items use 4 + n / 20, at least 8); items and nodes cost
// alike.
constexpr geometry::SahParams kSah{32, 1.0, 1.0, kNvMaxLeafSize};
constexpr int kBins = kSah.max_bins;
// Top levels: ranges of up to this many items take the exact sweep instead of bins.
constexpr uint32_t kSweepItems = 16;
// Below this many items a subtree is built on the calling thread.
constexpr uint32_t kParallelItems = 16384;

// One item: lane 3 of lo holds the item id, lane 3 of hi the item's bins on the last binning
// (find_split), read by the partition that follows (a normal float: see BinSet::add).
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

// sweep_area in float SSE for ranges whose box is tame (SahSplitter::cheapest): about half the
// work of the double version per cut.
float sweep_area_float(const Bounds4& b) {
    const __m128 d = _mm_sub_ps(b.hi, b.lo);
    const __m128 p = _mm_mul_ps(d, _mm_shuffle_ps(d, d, _MM_SHUFFLE(3, 0, 2, 1)));  // xy yz zx
    return _mm_cvtss_f32(_mm_add_ss(_mm_add_ss(p, _mm_shuffle_ps(p, p, _MM_SHUFFLE(1, 1, 1, 1))),
                                    _mm_movehl_ps(p, p)));
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

// The items of a range of up to kSweepItems, loaded once: boxes (lo's id lane zeroed) and
// centroid keys per axis (NaN as -inf, so it sorts first; lanes past the items +inf).
struct SmallItems {
    __m128 lo[kSweepItems], hi[kSweepItems];
    alignas(16) float key[3][kSweepItems];

    void load(const BoxRef* items, uint32_t n) {
        const __m128 inf = _mm_set1_ps(std::numeric_limits<float>::infinity()),
                     minus_inf = _mm_set1_ps(-std::numeric_limits<float>::infinity());
        for (int a = 0; a < 3; ++a)
            for (uint32_t b = 0; b < kSweepItems / 4; ++b) _mm_store_ps(key[a] + 4 * b, inf);
        alignas(16) float c[4];
        for (uint32_t k = 0; k < n; ++k) {
            lo[k] = load_lo(items[k]);
            hi[k] = _mm_load_ps(items[k].hi);
            const __m128 ck = centroid(lo[k], hi[k]), nan = _mm_cmpunord_ps(ck, ck);
            _mm_store_ps(c, _mm_or_ps(_mm_andnot_ps(nan, ck), _mm_and_ps(nan, minus_inf)));
            key[0][k] = c[0];
            key[1][k] = c[1];
            key[2][k] = c[2];
        }
    }

    // order[rank] = item, rank = how many items sort before it (a smaller key, or an equal key
    // at a lower position): the stable order, with no branches. Ranks are counted for four
    // items at once: an item j before their block sorts before each of them with a key <=
    // theirs, one after it with a key <, and one inside it by its position in the block.
    void order_by_centroid(uint32_t n, int axis, uint8_t* order) const {
        const float* const k = key[axis];
        const uint32_t padded = 4 * ((n + 3) / 4);  // padding items rank last, by position
        // Lanes above lane m: there an equal key of lane m counts as before.
        const __m128 above[4] = {_mm_castsi128_ps(_mm_setr_epi32(0, -1, -1, -1)),
                                 _mm_castsi128_ps(_mm_setr_epi32(0, 0, -1, -1)),
                                 _mm_castsi128_ps(_mm_setr_epi32(0, 0, 0, -1)), _mm_setzero_ps()};
        for (uint32_t b = 0; b < padded; b += 4) {
            const __m128 ki = _mm_load_ps(k + b);
            __m128i rank = _mm_setzero_si128();
            for (uint32_t j = 0; j < b; ++j)
                rank = _mm_sub_epi32(rank, _mm_castps_si128(_mm_cmple_ps(_mm_set1_ps(k[j]), ki)));
            for (uint32_t j = b + 4; j < padded; ++j)
                rank = _mm_sub_epi32(rank, _mm_castps_si128(_mm_cmplt_ps(_mm_set1_ps(k[j]), ki)));
            for (uint32_t m = 0; m < 4; ++m) {
                const __m128 km = _mm_set1_ps(k[b + m]);
                const __m128 before = _mm_or_ps(_mm_and_ps(above[m], _mm_cmple_ps(km, ki)),
                                                _mm_andnot_ps(above[m], _mm_cmplt_ps(km, ki)));
                rank = _mm_sub_epi32(rank, _mm_castps_si128(before));
            }
            alignas(16) int32_t r[4];
            _mm_store_si128(reinterpret_cast<__m128i*>(r), rank);
            for (uint32_t l = 0; l < 4; ++l) order[r[l]] = uint8_t(b + l);
        }
    }

    // The range of the items order[from..to) as they now lie at begin + from.., with bounds.
    Range bounds_of(const uint8_t* order, uint32_t from, uint32_t to, uint32_t begin) const {
        Range r{begin + from, begin + to, Bounds4::empty(), Bounds4::empty()};
        for (uint32_t k = from; k < to; ++k) {
            const __m128 l = lo[order[k]], h = hi[order[k]], c = centroid(l, h);
            r.box.grow(l, h);
            r.centroids.grow(c, c);
        }
        return r;
    }
};

// A BoxRef pad holding bins: 1.0f's bits, the bins in the mantissa.
constexpr uint32_t kPadBinsBase = 0x3f800000u;
static_assert(kBins <= 32, "a bin takes 5 bits of the pad");

// The bins of one range: per axis each bin's box and item count. A bin's count lies at the
// same byte offset in `count` as its box in `box`, so one offset per axis, computed in SIMD
// for all three, addresses both.
struct BinSet {
    Bounds4 box[3][kBins];
    struct alignas(32) Count {
        uint32_t n;
    } count[3][kBins];
    static_assert(sizeof(Count) == sizeof(Bounds4));

    void clear(int bins) {
        for (int a = 0; a < 3; ++a)
            for (int k = 0; k < bins; ++k) {
                box[a][k] = Bounds4::empty();
                count[a][k].n = 0;
            }
    }
    // Adds the item to its bin on each axis and keeps the three bins in its pad (5 bits each
    // at bits 0, 8 and 16, under 1.0f's exponent: lane 3 of `hi` stays a normal float, never
    // a denormal, whose multiplies in centroid() would take the slow path).
    void add(BoxRef& ref, const BinMap& map) {
        const __m128 lo = load_lo(ref), hi = _mm_load_ps(ref.hi);
        // Lane 3 of the bins is 0 (BinMap's scale and offset are 0 there), so that lane
        // carries the pad's top byte and lane 2 its exponent bit through the byte packing.
        const __m128i k = map.bins(centroid(lo, hi));
        static_assert(kPadBinsBase == (0x3fu << 24 | 0x80u << 16));
        __m128i pad = _mm_add_epi32(k, _mm_setr_epi32(0, 0, 0x80, 0x3f));
        pad = _mm_packus_epi16(_mm_packs_epi32(pad, pad), pad);
        ref.pad = uint32_t(_mm_cvtsi128_si32(pad));
        // Byte offsets of the three bins (under 2^16: one word each).
        const __m128i at =
            _mm_add_epi32(_mm_slli_epi32(k, 5),
                          _mm_setr_epi32(0, int(sizeof box[0]), int(2 * sizeof box[0]), 0));
        grow_bin(_mm_extract_epi16(at, 0), lo, hi);
        grow_bin(_mm_extract_epi16(at, 2), lo, hi);
        grow_bin(_mm_extract_epi16(at, 4), lo, hi);
    }

private:
    void grow_bin(int offset, __m128 lo, __m128 hi) {
        reinterpret_cast<Bounds4*>(reinterpret_cast<char*>(box) + offset)->grow(lo, hi);
        ++reinterpret_cast<Count*>(reinterpret_cast<char*>(count) + offset)->n;
    }
};

// Chooses the SAH splits over the shared BoxRef array (leaf `first` indexes it).
struct SahSplitter {
    BoxRef* refs;
    TreeLevel level;

    // The SAH core's cheapest split. Bottom levels evaluate the costs in float where every
    // bound of the range's box is within 2^40 (half areas under 2^84: times any item count far
    // below FLT_MAX, so only rounding in near ties differs from double), in about half the
    // work; huge or infinite boxes, and top levels, in double.
    template <int MaxBins, class BoxAt, class CountAt>
    Split cheapest(const Range& r, int bins, const bool usable[3], BoxAt box_at,
                   CountAt count_at) const {
        const __m128 abs_mask = _mm_castsi128_ps(_mm_set1_epi32(0x7fffffff)),
                     limit = _mm_set1_ps(0x1p40f);
        const __m128 tame = _mm_and_ps(_mm_cmple_ps(_mm_and_ps(r.box.lo, abs_mask), limit),
                                       _mm_cmple_ps(_mm_and_ps(r.box.hi, abs_mask), limit));
        if (level == TreeLevel::kBottom && (_mm_movemask_ps(tame) & 7) == 7) {
            const geometry::SahSplit<float> s =
                geometry::cheapest_split<float, MaxBins>(bins, usable, box_at, count_at,
                                                         Bounds4::empty(), sweep_area_float);
            return Split{s.axis, s.bin, double(s.cost)};
        }
        return geometry::cheapest_split<double, MaxBins>(bins, usable, box_at, count_at,
                                                         Bounds4::empty(), sweep_area);
    }

    // Bins the range's items: per axis each bin's box and count. Each item's three bins are
    // kept in its `pad` for the partition that follows.
    Split find_split(const Range& r, const BinMap& map) const {
        const int bins = map.bins_used;
        BinSet b;
        b.clear(bins);
        for (uint32_t i = r.begin; i < r.end; ++i) b.add(refs[i], map);
        return cheapest<kBins>(
            r, bins, map.usable, [&](int a, int k) -> const Bounds4& { return b.box[a][k]; },
            [&](int a, int k) { return b.count[a][k].n; });
    }

    // Hoare partition of [begin, end) by the split (left: bin <= split.bin, read from the
    // bins find_split kept in `pad`), gathering both sides' bounds on the way.
    void partition(const Range& r, const Split& s, Range* left, Range* right) const {
        Bounds4 lb = Bounds4::empty(), lc = Bounds4::empty(), rb = Bounds4::empty(),
                rc = Bounds4::empty();
        const int shift = 8 * s.axis;
        const uint32_t split_bin = uint32_t(s.bin);
        auto is_left = [&](const BoxRef& ref) { return ((ref.pad >> shift) & 31u) <= split_bin; };
        uint32_t i = r.begin, j = r.end;
        while (true) {
            while (i < j && is_left(refs[i])) {
                const __m128 lo = load_lo(refs[i]), hi = _mm_load_ps(refs[i].hi),
                             c = centroid(lo, hi);
                lb.grow(lo, hi);
                lc.grow(c, c);
                ++i;
            }
            while (i < j && !is_left(refs[j - 1])) {
                const __m128 lo = load_lo(refs[j - 1]), hi = _mm_load_ps(refs[j - 1].hi),
                             c = centroid(lo, hi);
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
    // The items are loaded once; the orders come from ranks, not from a sort.
    bool split_sorted(const Range& r, int depth, Range* left, Range* right) const {
        const uint32_t n = r.count();
        BoxRef* items = refs + r.begin;
        SmallItems small;
        small.load(items, n);
        bool usable[3];
        uint8_t order[3][kSweepItems];
        for (int a = 0; a < 3; ++a) {
            const double extent = double(lane(r.centroids.hi, a)) - lane(r.centroids.lo, a);
            usable[a] = extent > 0.0;  // false for coincident (or all-NaN) centroids
            if (usable[a]) small.order_by_centroid(n, a, order[a]);
        }
        const Split best = cheapest<kSweepItems>(
            r, int(n), usable,
            [&](int a, int k) {
                const int i = order[a][k];
                return Bounds4{small.lo[i], small.hi[i]};
            },
            [](int, int) { return 1u; });
        if (leaf_cheaper(r, best)) return false;
        if (best.axis < 0 || depth >= 64) {
            split_middle(r, left, right);
            return true;
        }
        BoxRef sorted[kSweepItems];
        for (uint32_t k = 0; k < n; ++k) sorted[k] = items[order[best.axis][k]];
        std::copy(sorted, sorted + n, items);
        const uint32_t cut = uint32_t(best.bin) + 1;
        *left = small.bounds_of(order[best.axis], 0, cut, r.begin);
        *right = small.bounds_of(order[best.axis], cut, n, r.begin);
        return true;
    }

    // split_sorted for two items (half of all its calls), with the same verdict and order:
    // the one cut costs the same on every axis (the sum of the two areas), so the first usable
    // axis takes it, and the items go in that axis's centroid order (NaN first, ties kept).
    bool split_pair(const Range& r, int depth, Range* left, Range* right) const {
        BoxRef* items = refs + r.begin;
        int axis = -1;
        for (int a = 0; a < 3 && axis < 0; ++a)
            if (double(lane(r.centroids.hi, a)) - lane(r.centroids.lo, a) > 0.0) axis = a;
        if (axis < 0) return false;  // coincident centroids: a leaf of two
        const Bounds4 b0{load_lo(items[0]), _mm_load_ps(items[0].hi)},
            b1{load_lo(items[1]), _mm_load_ps(items[1].hi)};
        if (leaf_cheaper(r, Split{axis, 0, sweep_area(b0) + sweep_area(b1)})) return false;
        if (depth < 64) {
            auto key = [&](const Bounds4& b) {
                const float c = lane(centroid(b.lo, b.hi), axis);
                return c == c ? c : -std::numeric_limits<float>::infinity();
            };
            if (key(b1) < key(b0)) std::swap(items[0], items[1]);
        }
        *left = bounds_of(r.begin, r.begin + 1);
        *right = bounds_of(r.begin + 1, r.end);
        return true;
    }

    // False for a leaf; otherwise the two children's ranges, the items reordered in place.
    bool split(const Range& r, int depth, Range* left, Range* right) const {
        const uint32_t count = r.count();
        if (count <= 1) return false;
        if (level == TreeLevel::kBottom) {
            // Embree's bins all the way down (4 + n/20, at least 4): on the bench meshes as
            // good a tree as the exact sweep of up to 16 items gave (SAH cost within 0.1%
            // but on the soup, +0.3%), for less work.
            if (count <= kSah.max_leaf_size) return false;
            return split_binned(r, depth, 4, left, right);
        }
        if (count == 2) return split_pair(r, depth, left, right);
        if (count <= kSweepItems) return split_sorted(r, depth, left, right);
        return split_binned(r, depth, 8, left, right);
    }

    // Bins the range (Embree's bin count 4 + n/20 between min_bins and 32: clearing and
    // sweeping 32 bins costs more than binning the items of a range of a few hundred) and
    // partitions it at the cheapest split, unless a leaf is cheaper.
    bool split_binned(const Range& r, int depth, uint32_t min_bins, Range* left,
                      Range* right) const {
        const uint32_t count = r.count();
        const BinMap map(r.centroids, int(std::clamp<uint32_t>(4 + count / 20, min_bins, kBins)));
        const Split best = find_split(r, map);
        if (leaf_cheaper(r, best)) return false;
        // Deep chains (e.g. exponentially spaced boxes) fall back to median splits so the
        // recursion stays shallow (depth <= 64 + log2 n).
        if (best.axis >= 0 && depth < 64)
            partition(r, best, left, right);
        else
            split_middle(r, left, right);  // centroids coincide: any split is as good
        if (left->count() == 0 || right->count() == 0) split_middle(r, left, right);
        return true;
    }
};

// Spreads the low 10 bits of x to every third bit.
constexpr uint32_t spread_bits(uint32_t x) {
    x &= 0x3ff;
    x = (x | (x << 16)) & 0x030000ff;
    x = (x | (x << 8)) & 0x0300f00f;
    x = (x | (x << 4)) & 0x030c30c3;
    x = (x | (x << 2)) & 0x09249249;
    return x;
}

// spread_bits of every 10-bit value: a Morton code takes three loads from this 4 KiB table
// instead of 24 shifts and masks (the codes are the same).
constexpr std::array<uint32_t, 1024> kSpreadBits = [] {
    std::array<uint32_t, 1024> t{};
    for (uint32_t x = 0; x < 1024; ++x) t[x] = spread_bits(x);
    return t;
}();

// Linear BVH over Morton codes (Lauterbach et al. 2009): the items sorted by the 30-bit
// code of their centroid, every node split where its range's highest differing code bit
// flips. One sort and one pass per level, no cost evaluation: the fast-build mode. The tree
// reads the sorted keys themselves (no unpacked copies of the codes or of the boxes in code
// order: those were 40 bytes written and read again per item) and fetches each leaf's boxes
// from input order, ahead of the leaves that need them.
struct MortonBuilder {
    const uint64_t* keys;  // sorted, code << 32 | item
    const Box* boxes;      // input order
    uint32_t* order;       // out: the item at each position of the code order
    uint32_t parallel_items;

    // Appends the subtree of [begin, end) to `out` (root at out.size()); returns its bounds.
    // Ranges of parallel_items and more build their halves as TBB tasks.
    Bounds4 build(std::vector<NvNode>& out, uint32_t begin, uint32_t end) const {
        if (end - begin < parallel_items) return build_sequential(out, begin, end);
        const uint32_t node = uint32_t(out.size());
        out.emplace_back();
        const uint32_t mid = split(begin, end);
        std::vector<NvNode> left_nodes, right_nodes;
        Bounds4 lb, rb;
        tbb::parallel_invoke([&] { lb = build(left_nodes, begin, mid); },
                             [&] { rb = build(right_nodes, mid, end); });
        geometry::splice_preorder(NvNodeEmitter{}, out, left_nodes);
        out[node].first = uint32_t(out.size());
        out[node].count = 0;
        geometry::splice_preorder(NvNodeEmitter{}, out, right_nodes);
        Bounds4 b = lb;
        b.grow(rb);
        NvNodeEmitter::set_bounds(out[node], b);
        return b;
    }

private:
    // Where [begin, end) (more than one leaf's items) splits: the first item whose code has
    // the range's highest differing bit set, or the middle when all codes are equal. The
    // codes of the range share every bit above that one, so those without it come first; a
    // binary search without branches on the data finds the first with it.
    uint32_t split(uint32_t begin, uint32_t end) const {
        const uint64_t diff = (keys[begin] ^ keys[end - 1]) >> 32;
        if (diff == 0) return begin + (end - begin) / 2;  // equal codes: any split is as good
        const uint64_t bit = uint64_t(1) << (63 - __builtin_clzll(diff) + 32);
        const uint64_t* base = keys + begin;
        for (uint32_t n = end - begin; n > 1;) {
            const uint32_t half = n / 2;
            base = (base[half] & bit) ? base : base + half;
            n -= half;
        }
        return uint32_t(base - keys) + ((*base & bit) ? 0 : 1);
    }

    // The leaf of [begin, end): its items' positions in `order` and their bounds, grown in
    // item order (which decides between -0 and +0). The boxes of the leaves kAhead positions
    // on are fetched meanwhile: leaves come in code order, their boxes from anywhere.
    Bounds4 leaf(uint32_t begin, uint32_t end, uint32_t size) const {
        constexpr uint32_t kAhead = 16;
        for (uint32_t i = begin + kAhead; i < end + kAhead && i < size; ++i)
            __builtin_prefetch(&boxes[uint32_t(keys[i])]);
        const __m128 xyz = _mm_castsi128_ps(_mm_set_epi32(0, -1, -1, -1));
        Bounds4 b = Bounds4::empty();
        for (uint32_t i = begin; i < end; ++i) {
            const uint32_t item = uint32_t(keys[i]);
            order[i] = item;
            // The box's six floats in two unaligned loads inside its 24 bytes.
            const __m128 tail = _mm_loadu_ps(boxes[item].lo + 2);
            b.grow(_mm_and_ps(_mm_loadu_ps(boxes[item].lo), xyz),
                   _mm_and_ps(_mm_shuffle_ps(tail, tail, _MM_SHUFFLE(3, 3, 2, 1)), xyz));
        }
        return b;
    }

    // build() on one thread, without recursion: the nodes in preorder, each inner node's
    // bounds written when its second child completes (most subtrees are small, so the node
    // is still in cache then). The bounds are grown in the order the recursive build grew
    // them (a leaf's items in order, then left and right child), which decides between -0
    // and +0.
    Bounds4 build_sequential(std::vector<NvNode>& out, uint32_t begin, uint32_t end) const {
        constexpr uint32_t kLeftChild = ~0u;  // a pending range whose parent needs no link
        struct Pending {
            uint32_t begin, end, parent;
        };
        // An inner node whose bounds wait for its children: its left child's once that is done.
        struct Open {
            uint32_t node;
            bool left_done;
            Bounds4 bounds;
        };
        std::vector<Pending> stack{{begin, end, kLeftChild}};
        std::vector<Open> open;
        Bounds4 done = Bounds4::empty();
        while (!stack.empty()) {
            const Pending p = stack.back();
            stack.pop_back();
            const uint32_t node = uint32_t(out.size());
            if (p.parent != kLeftChild) out[p.parent].first = node;
            NvNode& n = out.emplace_back();
            const uint32_t count = p.end - p.begin;
            if (count > kNvMaxLeafSize) {
                n.count = 0;
                open.push_back({node, false, Bounds4::empty()});
                const uint32_t mid = split(p.begin, p.end);
                stack.push_back({mid, p.end, node});
                stack.push_back({p.begin, mid, kLeftChild});
                continue;
            }
            done = leaf(p.begin, p.end, end);
            NvNodeEmitter::set_bounds(n, done);
            n.first = p.begin;
            n.count = count;
            // The subtree just done completes every open node whose right child it ends.
            while (!open.empty()) {
                Open& o = open.back();
                if (!o.left_done) {
                    o.left_done = true;
                    o.bounds = done;
                    break;
                }
                o.bounds.grow(done);
                done = o.bounds;
                NvNodeEmitter::set_bounds(out[o.node], done);
                open.pop_back();
            }
        }
        return done;
    }
};

// The radix sort's digits: 8 bits each, so that a pass scatters into 256 store streams, which
// L1 holds (1024 streams, 3 passes of 10 bits, missed it on about every store).
constexpr int kDigitBits = 8, kDigits = 4, kDigitValues = 1 << kDigitBits;
static_assert(kDigits * kDigitBits >= 30, "the digits cover a 30-bit Morton code");

// How many codes have each value of each digit: digit d's counts at kDigitValues * d.
using DigitCounts = std::array<uint32_t, kDigits * kDigitValues>;

void count_digits(uint32_t code, DigitCounts& counts) {
    for (int d = 0; d < kDigits; ++d)
        ++counts[kDigitValues * d + ((code >> (kDigitBits * d)) & (kDigitValues - 1))];
}

// Stable LSD radix sort of (code << 32 | item) keys by code, one pass per digit: equal codes
// keep item order, so the result depends only on the boxes. One 8-byte key per item keeps
// the scatter to one store stream per bucket; `counts` are the keys' digit counts
// (count_digits, taken while the codes were made), `spare` is working space (swapped with
// `keys` on the way).
void sort_by_code(std::vector<uint64_t>& keys, std::vector<uint64_t>& spare, DigitCounts& counts) {
    const size_t n = keys.size();
    spare.resize(n);
    for (int d = 0; d < kDigits; ++d) {
        uint32_t* start = counts.data() + kDigitValues * d;
        uint32_t sum = 0;
        for (int k = 0; k < kDigitValues; ++k) {
            const uint32_t c = start[k];
            start[k] = sum;
            sum += c;
        }
        const int shift = 32 + kDigitBits * d;
        for (size_t i = 0; i < n; ++i)
            spare[start[(keys[i] >> shift) & (kDigitValues - 1)]++] = keys[i];
        keys.swap(spare);
    }
}

// A build's working arrays, and the arrays of the last tree given back (recycle_tree), kept
// per thread between builds: fresh pages cost a fault and a clear each, which was about half
// of a Morton build's time on 10^5 triangles. A build takes them and gives them back, so a
// build nested on the same thread (a task stolen while waiting) finds none and allocates its
// own.
struct BuildScratch {
    std::vector<BoxRef> refs;
    std::vector<uint64_t> keys, spare;
    std::vector<NvNode> nodes;
    decltype(Tree::order) order;

    size_t bytes() const {
        return refs.capacity() * sizeof(BoxRef) +
               (keys.capacity() + spare.capacity()) * sizeof(uint64_t) +
               nodes.capacity() * sizeof(NvNode) + order.capacity() * sizeof(uint32_t);
    }
};

std::atomic<size_t> g_all_kept_bytes{0};

// The thread's kept arrays; their bytes count in g_all_kept_bytes until taken or the thread ends.
struct KeptScratch {
    BuildScratch scratch;
    ~KeptScratch() { g_all_kept_bytes -= scratch.bytes(); }
};
thread_local KeptScratch t_kept;

BuildScratch take_scratch() {
    g_all_kept_bytes -= t_kept.scratch.bytes();
    return std::move(t_kept.scratch);
}
void keep_scratch(BuildScratch&& s) {
    const size_t bytes = s.bytes();
    if (!claim_kept_bytes(bytes)) return;
    g_all_kept_bytes -= t_kept.scratch.bytes();  // (empty unless a nested build kept some)
    t_kept.scratch = std::move(s);
}

}  // namespace

bool claim_kept_bytes(size_t bytes) {
    if (bytes > kKeptBytesPerThread) return false;
    if (g_all_kept_bytes.fetch_add(bytes) + bytes > kAllKeptBytes) {
        g_all_kept_bytes -= bytes;
        return false;
    }
    return true;
}

void release_kept_bytes(size_t bytes) { g_all_kept_bytes -= bytes; }

void recycle_tree(Tree&& tree) {
    BuildScratch s = take_scratch();
    if (tree.nodes.capacity() > s.nodes.capacity()) s.nodes = std::move(tree.nodes);
    if (tree.order.capacity() > s.order.capacity()) s.order = std::move(tree.order);
    keep_scratch(std::move(s));
}

Box triangle_box(const float v[9]) {
    // Box::grow_point's rule in SSE: minps(p, lo) is p < lo ? p : lo, std::min(lo, p), so a
    // NaN coordinate is ignored the same way. v[9] is never read: the last vertex comes from
    // v[5..8], shifted down.
    const __m128 p0 = _mm_loadu_ps(v), p1 = _mm_loadu_ps(v + 3),
                 p2 = _mm_shuffle_ps(_mm_loadu_ps(v + 5), _mm_loadu_ps(v + 5),
                                     _MM_SHUFFLE(3, 3, 2, 1));
    const __m128 inf = _mm_set1_ps(std::numeric_limits<float>::infinity());
    const __m128 lo = _mm_min_ps(p2, _mm_min_ps(p1, _mm_min_ps(p0, inf)));
    const __m128 hi = _mm_max_ps(
        p2, _mm_max_ps(p1, _mm_max_ps(p0, _mm_set1_ps(-std::numeric_limits<float>::infinity()))));
    alignas(16) float l[4], h[4];
    _mm_store_ps(l, lo);
    _mm_store_ps(h, hi);
    return Box{{l[0], l[1], l[2]}, {h[0], h[1], h[2]}};
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

Tree build_tree(std::span<const Box> boxes, TreeQuality quality, TreeLevel level,
                const Box* centroids) {
    Tree t;
    if (boxes.empty()) return t;
    // One thread: no tasks and no splicing (the same bytes either way).
    // (global_control caps the threads without changing the arena's reported concurrency.)
    const size_t threads = std::min<size_t>(size_t(tbb::this_task_arena::max_concurrency()),
                                            tbb::global_control::active_value(
                                                tbb::global_control::max_allowed_parallelism));
    const uint32_t parallel_items = threads > 1 ? kParallelItems : ~0u;
    const uint32_t n = uint32_t(boxes.size());
    // A box's six floats in two unaligned loads inside its 24 bytes (lo0-2 hi0; lo2 hi0-2),
    // the fourth lanes zeroed.
    static_assert(sizeof(Box) == 24 && offsetof(Box, hi) == 12);
    auto load = [&](uint32_t i, __m128* lo, __m128* hi) {
        const __m128 xyz = _mm_castsi128_ps(_mm_set_epi32(0, -1, -1, -1));
        const __m128 tail = _mm_loadu_ps(boxes[i].lo + 2);
        *lo = _mm_and_ps(_mm_loadu_ps(boxes[i].lo), xyz);
        *hi = _mm_and_ps(_mm_shuffle_ps(tail, tail, _MM_SHUFFLE(3, 3, 2, 1)), xyz);
    };
    BuildScratch scratch = take_scratch();
    t.nodes = std::move(scratch.nodes);
    t.nodes.clear();
    t.order = std::move(scratch.order);
    if (quality == TreeQuality::kSah) {
        std::vector<BoxRef>& refs = scratch.refs;
        refs.resize(n);
        for (uint32_t i = 0; i < n; ++i) {
            BoxRef& r = refs[i];
            std::memcpy(r.lo, boxes[i].lo, 12);
            std::memcpy(r.hi, boxes[i].hi, 12);
            r.id = i;
            r.pad = 0;
        }
        const SahSplitter splitter{refs.data(), level};
        t.nodes.reserve(2 * size_t(n));
        geometry::TopDownBuilder<geometry::NodeLayout::kPreorder, Range, SahSplitter,
                                 NvNodeEmitter>(splitter, NvNodeEmitter{}, parallel_items)
            .append(t.nodes, splitter.bounds_of(0, n), 0);
        t.order.resize(n);
        for (uint32_t i = 0; i < n; ++i) t.order[i] = refs[i].id;
        keep_scratch(std::move(scratch));
        return t;
    }
    // Morton: the codes, sorted with their items, then the tree over the sorted keys.
    Bounds4 centroid_bounds = Bounds4::empty();
    if (centroids) {
        centroid_bounds.lo = _mm_setr_ps(centroids->lo[0], centroids->lo[1], centroids->lo[2], 0);
        centroid_bounds.hi = _mm_setr_ps(centroids->hi[0], centroids->hi[1], centroids->hi[2], 0);
    } else {
        for (uint32_t i = 0; i < n; ++i) {
            __m128 lo, hi;
            load(i, &lo, &hi);
            const __m128 c = centroid(lo, hi);
            centroid_bounds.grow(c, c);
        }
    }
    // 10 bits per axis over the centroid bounds (NaN and unusable axes quantize to 0).
    const BinMap map(centroid_bounds, 1024);
    std::vector<uint64_t>& keys = scratch.keys;
    keys.resize(n);
    DigitCounts counts{};
    for (uint32_t i = 0; i < n; ++i) {
        __m128 lo, hi;
        load(i, &lo, &hi);
        alignas(16) int32_t q[4];
        _mm_store_si128(reinterpret_cast<__m128i*>(q), map.bins(centroid(lo, hi)));
        const uint32_t code = kSpreadBits[uint32_t(q[0])] | kSpreadBits[uint32_t(q[1])] << 1 |
                              kSpreadBits[uint32_t(q[2])] << 2;
        keys[i] = uint64_t(code) << 32 | i;
        count_digits(code, counts);
    }
    t.nodes.reserve(size_t(n));  // leaves of up to 4 and Morton's uneven splits: about n nodes
    sort_by_code(keys, scratch.spare, counts);
    t.order.resize(n);
    MortonBuilder{keys.data(), boxes.data(), t.order.data(), parallel_items}.build(t.nodes, 0, n);
    keep_scratch(std::move(scratch));
    return t;
}

}  // namespace clastrace::engine::nv
