// SPDX-License-Identifier: Apache-2.0
// Four float lanes for the cluster build's box arithmetic and the NV traversal's 4-wide box
// test and its quantized boxes (nv_wide_tree.h): SSE2 where the target has it,
// plain C++ with the same lane semantics elsewhere (min/max return the second operand when
// the comparison is false, as minps/maxps do), so both give the same bytes.
#pragma once

#include <cstdint>
#include <cstring>
#include <limits>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace clastrace::engine::detail {

#if defined(__SSE2__)

struct Float4 {
    __m128 v;
};
struct Int4 {
    __m128i v;
};

inline Float4 splat(float x) { return {_mm_set1_ps(x)}; }
inline Float4 load4(const float* p) { return {_mm_load_ps(p)}; }  // 16-byte aligned
inline void store4(float* p, Float4 a) { _mm_store_ps(p, a.v); }
// x, y, z from p[0..2] (reads exactly 12 bytes), lane 3 = 0.
inline Float4 load3(const float* p) {
    double xy;
    std::memcpy(&xy, p, 8);
    return {_mm_movelh_ps(_mm_castpd_ps(_mm_set_sd(xy)), _mm_set_ss(p[2]))};
}
inline Float4 min4(Float4 a, Float4 b) { return {_mm_min_ps(a.v, b.v)}; }
inline Float4 max4(Float4 a, Float4 b) { return {_mm_max_ps(a.v, b.v)}; }
inline Float4 operator+(Float4 a, Float4 b) { return {_mm_add_ps(a.v, b.v)}; }
inline Float4 operator-(Float4 a, Float4 b) { return {_mm_sub_ps(a.v, b.v)}; }
inline Float4 operator*(Float4 a, Float4 b) { return {_mm_mul_ps(a.v, b.v)}; }
inline Float4 operator/(Float4 a, Float4 b) { return {_mm_div_ps(a.v, b.v)}; }
// |a|: the sign bit cleared (NaN stays NaN).
inline Float4 abs4(Float4 a) { return {_mm_andnot_ps(_mm_set1_ps(-0.0f), a.v)}; }
// Lane mask (bit k = lane k) of the lanes holding NaN.
inline unsigned nan_lanes(Float4 a) { return unsigned(_mm_movemask_ps(_mm_cmpunord_ps(a.v, a.v))); }
// Lane mask of the lanes where a <= b (false where either is NaN).
inline unsigned le_lanes(Float4 a, Float4 b) {
    return unsigned(_mm_movemask_ps(_mm_cmple_ps(a.v, b.v)));
}
// Conditions kept in the lanes (all bits set where true) and combined there, so that a test of
// several conditions moves one mask to a register (lanes) instead of one a condition.
struct Mask4 {
    __m128 v;
};
inline Mask4 operator&(Mask4 a, Mask4 b) { return {_mm_and_ps(a.v, b.v)}; }
inline Mask4 operator|(Mask4 a, Mask4 b) { return {_mm_or_ps(a.v, b.v)}; }
inline Mask4 le_mask(Float4 a, Float4 b) { return {_mm_cmple_ps(a.v, b.v)}; }  // NaN: false
inline Mask4 lt_mask(Float4 a, Float4 b) { return {_mm_cmplt_ps(a.v, b.v)}; }  // NaN: false
inline Mask4 nonzero_mask(Float4 a) { return {_mm_cmpneq_ps(a.v, _mm_setzero_ps())}; }  // NaN: true
inline unsigned lanes(Mask4 m) { return unsigned(_mm_movemask_ps(m.v)); }
// Truncation toward zero of lanes already inside [0, 2^31).
inline Int4 to_int(Float4 a) { return {_mm_cvttps_epi32(a.v)}; }
inline Float4 to_float(Int4 a) { return {_mm_cvtepi32_ps(a.v)}; }
inline void store_int4(int32_t* p, Int4 a) { _mm_storeu_si128(reinterpret_cast<__m128i*>(p), a.v); }
// Four bytes p[0..3], zero-extended, as float lanes (exact).
inline Float4 bytes_to_float4(const uint8_t* p) {
    int32_t bits;
    std::memcpy(&bits, p, 4);
    const __m128i zero = _mm_setzero_si128();
    const __m128i words = _mm_unpacklo_epi8(_mm_cvtsi32_si128(bits), zero);
    return {_mm_cvtepi32_ps(_mm_unpacklo_epi16(words, zero))};
}

#else

struct Float4 {
    float v[4];
};
struct Int4 {
    int32_t v[4];
};

inline Float4 splat(float x) { return {{x, x, x, x}}; }
inline Float4 load4(const float* p) { return {{p[0], p[1], p[2], p[3]}}; }
inline void store4(float* p, Float4 a) { std::memcpy(p, a.v, 16); }
inline Float4 load3(const float* p) { return {{p[0], p[1], p[2], 0.0f}}; }
#define CLASTRACE_LANES(expr)                    \
    Float4 r;                                    \
    for (int k = 0; k < 4; ++k) r.v[k] = (expr); \
    return r
inline Float4 min4(Float4 a, Float4 b) { CLASTRACE_LANES(a.v[k] < b.v[k] ? a.v[k] : b.v[k]); }
inline Float4 max4(Float4 a, Float4 b) { CLASTRACE_LANES(a.v[k] > b.v[k] ? a.v[k] : b.v[k]); }
inline Float4 operator+(Float4 a, Float4 b) { CLASTRACE_LANES(a.v[k] + b.v[k]); }
inline Float4 operator-(Float4 a, Float4 b) { CLASTRACE_LANES(a.v[k] - b.v[k]); }
inline Float4 operator*(Float4 a, Float4 b) { CLASTRACE_LANES(a.v[k] * b.v[k]); }
inline Float4 operator/(Float4 a, Float4 b) { CLASTRACE_LANES(a.v[k] / b.v[k]); }
inline Float4 abs4(Float4 a) {
    CLASTRACE_LANES(a.v[k] < 0.0f ? -a.v[k] : a.v[k] == 0.0f ? 0.0f : a.v[k]);
}
#undef CLASTRACE_LANES
inline unsigned nan_lanes(Float4 a) {
    unsigned m = 0;
    for (int k = 0; k < 4; ++k) m |= unsigned(a.v[k] != a.v[k]) << k;
    return m;
}
inline unsigned le_lanes(Float4 a, Float4 b) {
    unsigned m = 0;
    for (int k = 0; k < 4; ++k) m |= unsigned(a.v[k] <= b.v[k]) << k;
    return m;
}
struct Mask4 {
    unsigned bits;  // bit k: lane k
};
inline Mask4 operator&(Mask4 a, Mask4 b) { return {a.bits & b.bits}; }
inline Mask4 operator|(Mask4 a, Mask4 b) { return {a.bits | b.bits}; }
inline Mask4 le_mask(Float4 a, Float4 b) { return {le_lanes(a, b)}; }
inline Mask4 lt_mask(Float4 a, Float4 b) {
    unsigned m = 0;
    for (int k = 0; k < 4; ++k) m |= unsigned(a.v[k] < b.v[k]) << k;
    return {m};
}
inline Mask4 nonzero_mask(Float4 a) {
    unsigned m = 0;
    for (int k = 0; k < 4; ++k) m |= unsigned(a.v[k] != 0.0f) << k;
    return {m};
}
inline unsigned lanes(Mask4 m) { return m.bits; }
inline Int4 to_int(Float4 a) {
    return {{int32_t(a.v[0]), int32_t(a.v[1]), int32_t(a.v[2]), int32_t(a.v[3])}};
}
inline Float4 to_float(Int4 a) {
    return {{float(a.v[0]), float(a.v[1]), float(a.v[2]), float(a.v[3])}};
}
inline void store_int4(int32_t* p, Int4 a) { std::memcpy(p, a.v, 16); }
inline Float4 bytes_to_float4(const uint8_t* p) {
    return {{float(p[0]), float(p[1]), float(p[2]), float(p[3])}};
}

#endif

// Finite lanes: |x| <= FLT_MAX fails for NaN and infinity.
inline Mask4 finite_mask(Float4 a) {
    return le_mask(abs4(a), splat(std::numeric_limits<float>::max()));
}
inline unsigned finite_lanes(Float4 a) { return lanes(finite_mask(a)); }

}  // namespace clastrace::engine::detail
