// SPDX-License-Identifier: Apache-2.0
// Lays out a CLAS or template object (docs/engine-formats.md) from decoded input.
#include "cluster_internal.h"
#include "simd4.h"

#include "clastrace/common/debug_assert.h"

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstddef>

namespace clastrace::engine::detail {

namespace {

// 0, 1, ..., 255: the triangle order that needs no order section.
constexpr std::array<uint8_t, kMaxTriangles> kIdentityOrder = [] {
    std::array<uint8_t, kMaxTriangles> a{};
    for (uint32_t i = 0; i < kMaxTriangles; ++i) a[i] = uint8_t(i);
    return a;
}();

bool finite3(const float v[3]) {
    return std::isfinite(v[0]) && std::isfinite(v[1]) && std::isfinite(v[2]);
}

// Packs each coordinate's top `bits` bits (the truncated low bits are zero) into a
// little-endian bit stream.
void pack_positions(const float* positions, uint32_t count, uint32_t bits, uint32_t truncate,
                    std::byte* dst) {
    if (bits == 32) {
        std::memcpy(dst, positions, size_t(count) * 4);
        return;
    }
    if (bits == 0) return;
    uint64_t acc = 0;
    uint32_t acc_bits = 0;
    size_t out = 0;
    for (uint32_t i = 0; i < count; ++i) {
        const uint32_t pattern = std::bit_cast<uint32_t>(positions[i]) >> truncate;
        acc |= uint64_t(pattern) << acc_bits;
        acc_bits += bits;
        while (acc_bits >= 8) {
            dst[out++] = std::byte(acc & 0xFF);
            acc >>= 8;
            acc_bits -= 8;
        }
    }
    if (acc_bits > 0) dst[out++] = std::byte(acc & 0xFF);
}

#if !defined(__SSE2__)
// The first guess may be off by one either way (inv_step is rounded); the loops make it
// conservative with the exact decoding traversal uses.
uint8_t quantize_lo(const QuantFrame& f, const float inv_step[3], int a, float v) {
    const float rel = (v - f.lo[a]) * inv_step[a];
    int q = rel >= 255.0f ? 255 : (rel > 0.0f ? int(rel) : 0);
    while (q > 0 && dequant_lo(f, a, uint32_t(q)) > v) --q;
    return uint8_t(q);
}

uint8_t quantize_hi(const QuantFrame& f, const float inv_step[3], int a, float v) {
    const float rel = (v - f.lo[a]) * inv_step[a];
    // ceil of rel in (0, 255) as truncation plus one when rel has a fraction (exact there,
    // and no libm call on baseline x86-64, which lacks roundss).
    int q = 0;
    if (rel >= 255.0f)
        q = 255;
    else if (rel > 0.0f) {
        q = int(rel);
        q += float(q) < rel;
    }
    while (q < 255 && dequant_hi(f, a, uint32_t(q)) < v) ++q;
    return uint8_t(q);
}
#endif

// Every node's box quantized conservatively (quantize_lo/quantize_hi per bound) and its
// link, written as BvhNode records. The SSE2 path does the three axes of a bound at once
// with the same float operations, so it writes the same bytes.
void write_nodes(const QuantFrame& f, bool unbounded, const BvhScratch& s, uint32_t n_nodes,
                 std::byte* dst) {
    if (unbounded) {
        for (uint32_t i = 0; i < n_nodes; ++i) {
            const BvhScratch::Node& sn = s.nodes[i];
            BvhNode node{};
            for (int a = 0; a < 3; ++a) {
                node.qmin[a] = 0;
                node.qmax[a] = 255;
            }
            node.link = sn.link;
            std::memcpy(dst + 8 * i, &node, 8);
        }
        return;
    }
#if defined(__SSE2__)
    // Lane 3 carries v = lo = 0, step = 1: it never moves.
    const __m128 lo = _mm_setr_ps(f.lo[0], f.lo[1], f.lo[2], 0.0f);
    const __m128 step = _mm_setr_ps(f.step[0], f.step[1], f.step[2], 1.0f);
    const __m128 inv = _mm_div_ps(_mm_set1_ps(1.0f), step);
    const __m128 zero = _mm_setzero_ps(), top = _mm_set1_ps(255.0f);
    const __m128i izero = _mm_setzero_si128(), itop = _mm_set1_epi32(255);
    auto dequant = [&](__m128i q) { return _mm_add_ps(lo, _mm_mul_ps(_mm_cvtepi32_ps(q), step)); };
    for (uint32_t i = 0; i < n_nodes; ++i) {
        const BvhScratch::Node& sn = s.nodes[i];
        const __m128 vlo = _mm_load_ps(sn.lo), vhi = _mm_load_ps(sn.hi);
        // max(x, 0) with x second-false takes 0 for NaN, like the scalar `rel > 0` test.
        const __m128 xlo = _mm_min_ps(_mm_max_ps(_mm_mul_ps(_mm_sub_ps(vlo, lo), inv), zero), top);
        const __m128 xhi = _mm_min_ps(_mm_max_ps(_mm_mul_ps(_mm_sub_ps(vhi, lo), inv), zero), top);
        __m128i qlo = _mm_cvttps_epi32(xlo);
        __m128i qhi = _mm_cvttps_epi32(xhi);
        qhi =
            _mm_sub_epi32(qhi, _mm_castps_si128(_mm_cmplt_ps(_mm_cvtepi32_ps(qhi), xhi)));  // ceil
        // The first guesses are almost always right: one test of both before the loops.
        const __m128i down = _mm_and_si128(_mm_cmpgt_epi32(qlo, izero),
                                           _mm_castps_si128(_mm_cmpgt_ps(dequant(qlo), vlo)));
        const __m128i up = _mm_and_si128(_mm_cmplt_epi32(qhi, itop),
                                         _mm_castps_si128(_mm_cmplt_ps(dequant(qhi), vhi)));
        if (_mm_movemask_epi8(_mm_or_si128(down, up))) {
            for (;;) {
                const __m128i d = _mm_and_si128(_mm_cmpgt_epi32(qlo, izero),
                                                _mm_castps_si128(_mm_cmpgt_ps(dequant(qlo), vlo)));
                if (!_mm_movemask_epi8(d)) break;
                qlo = _mm_add_epi32(qlo, d);
            }
            for (;;) {
                const __m128i u = _mm_and_si128(_mm_cmplt_epi32(qhi, itop),
                                                _mm_castps_si128(_mm_cmplt_ps(dequant(qhi), vhi)));
                if (!_mm_movemask_epi8(u)) break;
                qhi = _mm_sub_epi32(qhi, u);
            }
        }
        // The six quantized bounds (0..255) as bytes in SSE: qmin x y z 0 qmax x y z 0, the
        // qmax bytes moved down one onto the 0, the link in the top two bytes.
        const __m128i q16 = _mm_packs_epi32(qlo, qhi);
        const __m128i q8 = _mm_packus_epi16(q16, q16);
        const __m128i low3 = _mm_setr_epi8(-1, -1, -1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0);
        const __m128i bounds =
            _mm_or_si128(_mm_and_si128(low3, q8), _mm_andnot_si128(low3, _mm_srli_si128(q8, 1)));
        const __m128i with_link = _mm_insert_epi16(bounds, sn.link, 3);
        static_assert(sizeof(BvhNode) == 8 && offsetof(BvhNode, qmax) == 3 &&
                      offsetof(BvhNode, link) == 6);
        _mm_storel_epi64(reinterpret_cast<__m128i*>(dst + 8 * i), with_link);  // little endian
    }
#else
    float inv_step[3];
    for (int a = 0; a < 3; ++a) inv_step[a] = 1.0f / f.step[a];
    for (uint32_t i = 0; i < n_nodes; ++i) {
        const BvhScratch::Node& sn = s.nodes[i];
        BvhNode node{};
        for (int a = 0; a < 3; ++a) {
            node.qmin[a] = quantize_lo(f, inv_step, a, sn.lo[a]);
            node.qmax[a] = quantize_hi(f, inv_step, a, sn.hi[a]);
        }
        node.link = sn.link;
        std::memcpy(dst + 8 * i, &node, 8);
    }
#endif
}

// Section offsets and flags of the header, and the object's size (also in the header).
uint32_t lay_out_object(ObjectHeader& h, const EncodeInput& in, uint32_t n_nodes, bool identity,
                        bool varying) {
    const uint32_t n_triangles = in.triangle_count;
    uint32_t size = sizeof(ObjectHeader);
    if (n_nodes) {
        h.nodes_offset = size;
        h.node_count = uint16_t(n_nodes);
        size += 8 * n_nodes;
    }
    const uint32_t pos_bytes =
        in.positions ? packed_section_size(in.vertex_count, h.position_bits) : 0;
    if (in.positions) {
        h.header_flags |= kHasPositions;
        h.positions_offset = size;
        size = align4(size + pos_bytes);
    }
    h.indices_offset = size;
    size += 3 * n_triangles;
    if (!identity) {
        h.header_flags |= kHasTriangleOrder;
        h.triangle_order_offset = size;
        size += n_triangles;
    }
    size = align4(size);
    if (varying) {
        h.header_flags |= kHasTriangleData;
        h.triangle_data_offset = size;
        size += 4 * n_triangles;
    }
    if (in.has_omm) {
        h.header_flags |= kHasOpacityMicromap;
        size = (size + 7u) & ~7u;
        h.omm_offset = size;
        size += sizeof(OpacityMicromapSection) + 4 * n_triangles;
    }
    if (in.has_bounds_limit) {
        h.header_flags |= kHasBoundsLimit;
        h.bounds_limit_offset = size;
        size += 24;
    }
    size = align4(size);
    h.object_size = size;
    return size;
}

// Per-triangle sections in stored order, one loop each (no per-triangle tests of which
// sections exist).
void write_triangle_sections(const EncodeInput& in, const ObjectHeader& h, const uint8_t* order,
                             bool identity, bool varying, std::byte* base) {
    const uint32_t n_triangles = in.triangle_count;
    std::byte* const index_section = base + h.indices_offset;
    const bool any_dead = in.inactive && std::memchr(in.inactive, 1, n_triangles) != nullptr;
    // Each triangle's three as one 4-byte load and store (the fourth byte is the next
    // triangle's, overwritten by it), the last one's bytewise: nothing past the section moves.
#pragma GCC unroll 4
    for (uint32_t i = 0; i + 1 < n_triangles; ++i) {
        uint32_t three;
        std::memcpy(&three, in.index_bytes + 3 * size_t(order[i]), 4);
        std::memcpy(index_section + 3 * size_t(i), &three, 4);
    }
    if (n_triangles > 0) {
        const size_t last = n_triangles - 1, from = 3 * size_t(order[last]);
        for (int v = 0; v < 3; ++v)
            index_section[3 * last + v] = std::byte(in.index_bytes[from + v]);
    }
    if (any_dead)
        for (uint32_t i = 0; i < n_triangles; ++i)
            if (in.inactive[order[i]])  // dead ones stay 0
                for (int v = 0; v < 3; ++v) index_section[3 * i + v] = std::byte{0};
    if (!identity) std::memcpy(base + h.triangle_order_offset, order, n_triangles);
    if (varying)
        for (uint32_t i = 0; i < n_triangles; ++i)
            std::memcpy(base + h.triangle_data_offset + 4 * i,
                        &in.geometry_index_and_flags[order[i]], 4);
    if (in.has_omm)
        for (uint32_t i = 0; i < n_triangles; ++i)
            std::memcpy(base + h.omm_offset + sizeof(OpacityMicromapSection) + 4 * i,
                        &in.omm_indices[order[i]], 4);
    if (in.has_omm) {
        OpacityMicromapSection sec{};
        sec.opacity_micromap_array = in.omm_array;
        sec.index_type = in.omm_index_type;
        std::memcpy(base + h.omm_offset, &sec, sizeof sec);
    }
}

// A centroid with NaN lanes (infinities that cancel) with those lanes 0.
Float4 nan_lanes_to_zero(Float4 c) {
    alignas(16) float lanes[4];
    store4(lanes, c);
    for (float& x : lanes)
        if (x != x) x = 0.0f;
    return load4(lanes);
}

// The gathers' last step: the centroids' bounds into the BVH scratch, and the bounds over the
// active triangles' vertices (left as given when none is active).
void store_bounds(BvhScratch& s, Float4 centroid_lo, Float4 centroid_hi, uint32_t n_active,
                  Float4 lo_all, Float4 hi_all, float bmin[3], float bmax[3]) {
    store4(s.centroid_min, centroid_lo);
    store4(s.centroid_max, centroid_hi);
    if (n_active > 0) {
        alignas(16) float lo4[4], hi4[4];
        store4(lo4, lo_all);
        store4(hi4, hi_all);
        std::memcpy(bmin, lo4, 3 * sizeof(float));
        std::memcpy(bmax, hi4, 3 * sizeof(float));
    }
}

// One pass over the triangles (inactive ones skipped when kSkipInactive) gathers each active
// triangle's box and centroid into the BVH scratch (what its build starts from), with the
// centroids' bounds, its index into `active`, and the bounds over them (the bounds over the
// vertices active triangles use, left as given when none is active). A triangle with a NaN
// coordinate is not active. Returns the active count.
template <bool kSkipInactive>
uint32_t gather_active_boxes(const EncodeInput& in, BvhScratch& s, uint8_t* active, bool& any_nan,
                             float bmin[3], float bmax[3]) {
    uint32_t n_active = 0;
    Float4 lo_all = splat(INFINITY), hi_all = splat(-INFINITY);
    Float4 centroid_lo = lo_all, centroid_hi = hi_all;
    const Float4 half = splat(0.5f);
    for (uint32_t t = 0; t < in.triangle_count; ++t) {
        if (kSkipInactive && in.inactive[t]) continue;
        const uint8_t* tri = in.index_bytes + 3 * t;
        const Float4 a = load3(in.positions + 3 * tri[0]);
        const Float4 b = load3(in.positions + 3 * tri[1]);
        const Float4 c = load3(in.positions + 3 * tri[2]);
        // The sum is NaN when a coordinate is (and when infinities cancel): one test for the
        // common case, the exact one only then.
        if (nan_lanes(a + b + c) && (nan_lanes(a) | nan_lanes(b) | nan_lanes(c))) {
            any_nan = true;
            continue;
        }
        const Float4 lo = min4(a, min4(b, c)), hi = max4(a, max4(b, c));
        store4(s.tri_min[n_active], lo);
        store4(s.tri_max[n_active], hi);
        lo_all = min4(lo_all, lo);
        hi_all = max4(hi_all, hi);
        Float4 centroid = lo * half + hi * half;
        if (nan_lanes(centroid)) centroid = nan_lanes_to_zero(centroid);
        store4(s.centroid[n_active], centroid);
        centroid_lo = min4(centroid_lo, centroid);
        centroid_hi = max4(centroid_hi, centroid);
        active[n_active++] = uint8_t(t);
    }
    store_bounds(s, centroid_lo, centroid_hi, n_active, lo_all, hi_all, bmin, bmax);
    return n_active;
}

// The cluster's vertices as 16-byte lanes x, y, z, 0 (one aligned load each for the triangles
// that use them). Returns whether every coordinate is finite.
bool widen_vertices(const float* positions, uint32_t count, float (*vertex)[4]) {
    Float4 any_bad = splat(0.0f);  // x - x is 0 for a finite x, NaN for infinities and NaN
#pragma GCC unroll 2
    for (uint32_t v = 0; v < count; ++v) {
        const Float4 p = load3(positions + 3 * size_t(v));
        store4(vertex[v], p);
        any_bad = any_bad + (p - p);
    }
    return nan_lanes(any_bad) == 0;
}

// gather_active_boxes for a cluster whose triangles are all active and whose vertices are all
// finite (the common case): the same boxes, centroids and bounds without the tests (no
// coordinate is NaN, and half-sums of finite corners are finite), each corner one load, no
// active list (every triangle is).
uint32_t gather_finite_boxes(const EncodeInput& in, const float (*vertex)[4], BvhScratch& s,
                             float bmin[3], float bmax[3]) {
    const uint32_t n = in.triangle_count;
    const uint8_t* const index_bytes = in.index_bytes;
    Float4 lo_all = splat(INFINITY), hi_all = splat(-INFINITY);
    Float4 centroid_lo = lo_all, centroid_hi = hi_all;
    const Float4 half = splat(0.5f);
#pragma GCC unroll 2
    for (size_t t = 0; t < n; ++t) {
        const uint8_t* tri = index_bytes + 3 * t;
        const Float4 a = load4(vertex[tri[0]]);
        const Float4 b = load4(vertex[tri[1]]);
        const Float4 c = load4(vertex[tri[2]]);
        const Float4 lo = min4(a, min4(b, c)), hi = max4(a, max4(b, c));
        store4(s.tri_min[t], lo);
        store4(s.tri_max[t], hi);
        lo_all = min4(lo_all, lo);
        hi_all = max4(hi_all, hi);
        const Float4 centroid = lo * half + hi * half;
        store4(s.centroid[t], centroid);
        centroid_lo = min4(centroid_lo, centroid);
        centroid_hi = max4(centroid_hi, centroid);
    }
    store_bounds(s, centroid_lo, centroid_hi, n, lo_all, hi_all, bmin, bmax);
    return n;
}

// Copies `size` bytes (a multiple of 4) with non-temporal stores: 4-byte ones up to the first
// 16-byte boundary and after the last, 16-byte ones between. Fenced: a thread that later
// synchronizes with this one (a release / acquire pair, which does not order non-temporal
// stores by itself) sees every byte.
void stream_copy(std::byte* dst, const std::byte* src, size_t size) {
#if defined(__SSE2__)
    if (reinterpret_cast<uintptr_t>(dst) % 4 == 0) {
        size_t i = 0;
        const auto put4 = [&] {
            int32_t word;
            std::memcpy(&word, src + i, 4);
            _mm_stream_si32(reinterpret_cast<int*>(dst + i), word);
            i += 4;
        };
        const auto put16 = [&](size_t at) {
            _mm_stream_si128(reinterpret_cast<__m128i*>(dst + at),
                             _mm_loadu_si128(reinterpret_cast<const __m128i*>(src + at)));
        };
        while (i < size && reinterpret_cast<uintptr_t>(dst + i) % 16 != 0) put4();
        for (; i + 64 <= size; i += 64) {  // a line's worth per loop end (GCC unrolls none)
            put16(i);
            put16(i + 16);
            put16(i + 32);
            put16(i + 48);
        }
        for (; i + 16 <= size; i += 16) put16(i);
        while (i < size) put4();
        _mm_sfence();
        return;
    }
#endif
    std::memcpy(dst, src, size);
}

}  // namespace

uint32_t encode_object(const EncodeInput& in, EncodeScratch& scratch, ObjectStores stores,
                       std::vector<std::byte>& out) {
    BvhScratch& s = scratch.bvh;
    ObjectHeader h{};
    h.magic = kObjectMagic;
    h.object_type = uint8_t(in.type);
    h.format_version = kFormatVersion;
    h.cluster_id = in.cluster_id;
    h.triangle_count = uint16_t(in.triangle_count);
    h.vertex_count = uint16_t(in.vertex_count);
    h.position_truncate_bits = uint8_t(in.truncate_bits);
    h.position_bits = uint8_t(32 - in.truncate_bits);
    h.cluster_flags = uint8_t(in.cluster_flags);
    h.base_geometry_index_and_flags = in.base_geometry_index_and_flags;
    h.vertex_format = in.vertex_format;
    const uint32_t n_triangles = in.triangle_count;
    const bool is_clas = in.type == ObjectType::kTriangleCluster;
    // Active triangles: indices in range and no NaN coordinate (after truncation).
    uint8_t active[kMaxTriangles];
    bool any_nan = false;
    float bmin[3] = {0.0f, 0.0f, 0.0f}, bmax[3] = {0.0f, 0.0f, 0.0f};
    uint32_t n_active = 0;
    if (in.positions) {
        const bool any_inactive =
            in.inactive && std::memchr(in.inactive, 1, n_triangles) != nullptr;
        if (any_inactive)
            n_active = gather_active_boxes<true>(in, s, active, any_nan, bmin, bmax);
        else if (in.vertex_count > 0 &&  // else an instance of a hostile template's index 0
                 widen_vertices(in.positions, in.vertex_count, scratch.vertex))
            n_active = gather_finite_boxes(in, scratch.vertex, s, bmin, bmax);
        else
            n_active = gather_active_boxes<false>(in, s, active, any_nan, bmin, bmax);
    }
    std::memcpy(h.bounds_min, bmin, sizeof bmin);
    std::memcpy(h.bounds_max, bmax, sizeof bmax);

    // Triangle order: BVH order for a CLAS (inactive triangles after the active ones),
    // the application's order for a template.
    uint8_t order[kMaxTriangles];
    uint32_t n_nodes = 0;
    bool identity = true;
    if (is_clas && n_active > 0) {
        // Told by the BVH, not compared here: its order was just stored a byte at a time, and
        // memcmp's wide loads would wait for those stores.
        identity = build_bvh(n_active < n_triangles ? active : nullptr, n_active, s, order);
        n_nodes = s.node_count;
        if (n_active < n_triangles) {
            bool is_active[kMaxTriangles] = {};
            for (uint32_t i = 0; i < n_active; ++i) is_active[active[i]] = true;
            uint32_t k = n_active;
            for (uint32_t t = 0; t < n_triangles; ++t)
                if (!is_active[t]) {
                    identity &= t == k;
                    order[k++] = uint8_t(t);
                }
        }
    } else {
        std::memcpy(order, kIdentityOrder.data(), n_triangles);
    }

    bool varying = false;
    uint32_t max_geometry_index = in.base_geometry_index_and_flags & 0xFFFFFFu;
    if (in.geometry_index_and_flags && n_triangles > 0) {
        max_geometry_index = 0;
        for (uint32_t t = 0; t < n_triangles; ++t) {
            varying |= in.geometry_index_and_flags[t] != in.geometry_index_and_flags[0];
            max_geometry_index =
                std::max(max_geometry_index, in.geometry_index_and_flags[t] & 0xFFFFFFu);
        }
        if (!varying) h.base_geometry_index_and_flags = in.geometry_index_and_flags[0];
    }
    h.max_geometry_index = max_geometry_index;

    const QuantFrame frame = make_frame(bmin, bmax);
    bool unbounded = !finite3(bmin) || !finite3(bmax);
    for (int a = 0; a < 3; ++a) unbounded |= !std::isfinite(frame.step[a]);

    const uint32_t size = lay_out_object(h, in, n_nodes, identity, varying);
    if (unbounded) h.header_flags |= kUnboundedNodes;
    if (any_nan) h.header_flags |= kHasNaNTriangles;

    const bool streamed = stores == ObjectStores::kStreaming;
    CLASTRACE_DEBUG_ASSERT(size <= kMaxObjectBytes);
    if (!streamed) out.assign(size, std::byte{0});
    std::byte* const base = streamed ? scratch.object : out.data();
    if (streamed) std::memset(base, 0, size);

    write_nodes(frame, unbounded, s, n_nodes, base + h.nodes_offset);
    if (in.positions)
        pack_positions(in.positions, 3 * in.vertex_count, h.position_bits, in.truncate_bits,
                       base + h.positions_offset);
    write_triangle_sections(in, h, order, identity, varying, base);
    if (in.has_bounds_limit) std::memcpy(base + h.bounds_limit_offset, in.bounds_limit, 24);
    // The header last: its fields were just stored one by one, and the copy's wide loads
    // cannot be forwarded from those stores (they wait for them to reach the cache); the
    // sections' work in between lets them get there.
    std::memcpy(base, &h, sizeof h);
    if (streamed) {
        out.resize(size);  // a rebuild's vector already has the size: nothing written
        stream_copy(out.data(), base, size);
    }
    return size;
}

}  // namespace clastrace::engine::detail
