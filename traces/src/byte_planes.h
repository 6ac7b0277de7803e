// SPDX-License-Identifier: Apache-2.0
// The 4 byte planes of MemoryContentsDelta.byte_planes 4 and of whole contents in a streams
// payload (docs/trace-format.md): byte i of the
// first n - n % 4 bytes goes to plane i % 4, at i / 4 in it; the tail stays where it is. An XOR
// of 32-bit floats that changed a little is zero in its high bytes and busy in its low ones:
// planes put the zeros together, which zstd stores in less than the interleaved bytes.
// (Byte 0 of a word is its low byte: file_format.h asserts a little-endian host.)
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstring>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace clastrace::traces::format {

// planes = the n bytes of (bytes XOR base), laid out in planes (kXor false: of bytes alone,
// base unused). `planes` aliases neither input.
template <bool kXor>
inline void spread_to_byte_planes(const uint8_t* bytes, const uint8_t* base, size_t n,
                                  uint8_t* planes) {
    const size_t m = n / 4;
    uint8_t* p0 = planes;
    uint8_t* p1 = planes + m;
    uint8_t* p2 = planes + 2 * m;
    uint8_t* p3 = planes + 3 * m;
    size_t i = 0;
#if defined(__SSE2__)
    // 16 words at a time: each byte of a word masked out and packed down to one byte per word
    // (the values fit, so the saturating packs change nothing).
    const __m128i low_byte = _mm_set1_epi32(0xff);
    for (; i + 16 <= m; i += 16) {
        __m128i w[4];
        for (int k = 0; k < 4; ++k) {
            w[k] = _mm_loadu_si128(reinterpret_cast<const __m128i*>(bytes + 4 * i) + k);
            if constexpr (kXor)
                w[k] = _mm_xor_si128(w[k], _mm_loadu_si128(
                                               reinterpret_cast<const __m128i*>(base + 4 * i) + k));
        }
        uint8_t* to[4] = {p0, p1, p2, p3};
        for (int plane = 0; plane < 4; ++plane) {
            __m128i v[4];
            for (int k = 0; k < 4; ++k)
                v[k] = _mm_and_si128(_mm_srli_epi32(w[k], 8 * plane), low_byte);
            const __m128i packed =
                _mm_packus_epi16(_mm_packs_epi32(v[0], v[1]), _mm_packs_epi32(v[2], v[3]));
            _mm_storeu_si128(reinterpret_cast<__m128i*>(to[plane] + i), packed);
        }
    }
#endif
    for (; i < m; ++i) {  // one 32-bit word at a time
        uint32_t x, b = 0;
        std::memcpy(&x, bytes + 4 * i, 4);
        if constexpr (kXor) std::memcpy(&b, base + 4 * i, 4);
        x ^= b;  // little-endian: byte 0 of the word is its low byte
        p0[i] = uint8_t(x);
        p1[i] = uint8_t(x >> 8);
        p2[i] = uint8_t(x >> 16);
        p3[i] = uint8_t(x >> 24);
    }
    for (size_t i = 4 * m; i < n; ++i) planes[i] = kXor ? bytes[i] ^ base[i] : bytes[i];
}

inline void xor_to_byte_planes(const uint8_t* bytes, const uint8_t* base, size_t n,
                               uint8_t* planes) {
    spread_to_byte_planes<true>(bytes, base, n, planes);
}

// planes = the n bytes laid out in planes (whole contents, chunk_streams.h).
inline void to_byte_planes(const uint8_t* bytes, size_t n, uint8_t* planes) {
    spread_to_byte_planes<false>(bytes, nullptr, n, planes);
}

// out = base XOR the n bytes that `planes` lays out (the reader's half; kXor false: those
// bytes alone, base unused). `out` may be `base`, never `planes`.
template <bool kXor>
inline void gather_from_byte_planes(const uint8_t* planes, const uint8_t* base, size_t n,
                                    uint8_t* out) {
    const size_t m = n / 4;
    const uint8_t* p0 = planes;
    const uint8_t* p1 = planes + m;
    const uint8_t* p2 = planes + 2 * m;
    const uint8_t* p3 = planes + 3 * m;
    size_t i = 0;
#if defined(__SSE2__)
    // 16 words at a time: planes 0 and 1, then 2 and 3, interleaved by bytes, the two results
    // by 16-bit halves, give the words in order (byte 0 of a word is its low byte).
    for (; i + 16 <= m; i += 16) {
        const auto plane = [&](const uint8_t* p) {
            return _mm_loadu_si128(reinterpret_cast<const __m128i*>(p + i));
        };
        const __m128i a = plane(p0), b = plane(p1), c = plane(p2), d = plane(p3);
        const __m128i ab_low = _mm_unpacklo_epi8(a, b), ab_high = _mm_unpackhi_epi8(a, b);
        const __m128i cd_low = _mm_unpacklo_epi8(c, d), cd_high = _mm_unpackhi_epi8(c, d);
        const __m128i words[4] = {_mm_unpacklo_epi16(ab_low, cd_low),
                                  _mm_unpackhi_epi16(ab_low, cd_low),
                                  _mm_unpacklo_epi16(ab_high, cd_high),
                                  _mm_unpackhi_epi16(ab_high, cd_high)};
        for (int k = 0; k < 4; ++k) {
            auto* to = reinterpret_cast<__m128i*>(out + 4 * i) + k;
            if constexpr (kXor) {
                const auto* from = reinterpret_cast<const __m128i*>(base + 4 * i) + k;
                _mm_storeu_si128(to, _mm_xor_si128(_mm_loadu_si128(from), words[k]));
            } else {
                _mm_storeu_si128(to, words[k]);
            }
        }
    }
#endif
    for (; i < m; ++i) {
        uint32_t b = 0;
        if constexpr (kXor) std::memcpy(&b, base + 4 * i, 4);
        const uint32_t x =
            uint32_t(p0[i]) | uint32_t(p1[i]) << 8 | uint32_t(p2[i]) << 16 | uint32_t(p3[i]) << 24;
        b ^= x;
        std::memcpy(out + 4 * i, &b, 4);
    }
    for (size_t i = 4 * m; i < n; ++i) out[i] = kXor ? base[i] ^ planes[i] : planes[i];
}

inline void xor_from_byte_planes(const uint8_t* planes, const uint8_t* base, size_t n,
                                 uint8_t* out) {
    gather_from_byte_planes<true>(planes, base, n, out);
}

// out = the n bytes that `planes` lays out. `out` never aliases `planes`.
inline void from_byte_planes(const uint8_t* planes, size_t n, uint8_t* out) {
    gather_from_byte_planes<false>(planes, nullptr, n, out);
}

}  // namespace clastrace::traces::format
