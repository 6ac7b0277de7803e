// SPDX-License-Identifier: Apache-2.0
#include "clastrace/capture/uncached_copy.h"

#include <algorithm>
#include <cstring>

#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>
#define CLASTRACE_STREAM_LOADS 1
#endif

namespace clastrace::capture {

#ifdef CLASTRACE_STREAM_LOADS
namespace {

__attribute__((target("sse4.1"))) void stream_copy(uint8_t* destination, const uint8_t* source,
                                                   size_t size) {
    // Streaming loads need 16-byte aligned sources: the unaligned head and the tail go by memcpy.
    const size_t head =
        std::min(size, size_t((16 - (reinterpret_cast<uintptr_t>(source) & 15)) & 15));
    std::memcpy(destination, source, head);
    destination += head;
    source += head;
    size -= head;
    // Four loads a line, issued together, so each line is fetched once.
    for (; size >= 64; size -= 64, source += 64, destination += 64) {
        auto* s = reinterpret_cast<__m128i*>(const_cast<uint8_t*>(source));
        const __m128i a = _mm_stream_load_si128(s), b = _mm_stream_load_si128(s + 1),
                      c = _mm_stream_load_si128(s + 2), d = _mm_stream_load_si128(s + 3);
        auto* out = reinterpret_cast<__m128i*>(destination);
        _mm_storeu_si128(out, a);
        _mm_storeu_si128(out + 1, b);
        _mm_storeu_si128(out + 2, c);
        _mm_storeu_si128(out + 3, d);
    }
    for (; size >= 16; size -= 16, source += 16, destination += 16)
        _mm_storeu_si128(reinterpret_cast<__m128i*>(destination),
                         _mm_stream_load_si128(
                             reinterpret_cast<__m128i*>(const_cast<uint8_t*>(source))));
    std::memcpy(destination, source, size);
}

bool have_stream_loads() {
    static const bool kHave = __builtin_cpu_supports("sse4.1");
    return kHave;
}

}  // namespace
#endif

void copy_from_uncached(uint8_t* destination, const uint8_t* source, size_t size) {
#ifdef CLASTRACE_STREAM_LOADS
    // Below a few lines the setup costs more than it saves.
    if (size >= 256 && have_stream_loads()) return stream_copy(destination, source, size);
#endif
    if (size) std::memcpy(destination, source, size);
}

}  // namespace clastrace::capture
