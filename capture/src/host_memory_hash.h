// SPDX-License-Identifier: Apache-2.0
// The body of hash_host_memory (clastrace/capture/uncached_copy.h), compiled twice: for the
// baseline target and, where the processor has it, with AVX2 (host_memory_hash_avx2.cpp).
// xxhash picks its vector code by the compiler's target, and the hash is the same either way;
// each translation unit gets its own copy (an anonymous namespace; no inline function of the
// standard library either, whose one kept copy could be the AVX2 one), so the two never mix.
#pragma once

#include "clastrace/capture/uncached_copy.h"

#include <cstddef>
#include <cstdint>

#define XXH_INLINE_ALL
#include <xxhash.h>

namespace clastrace::capture {
namespace {

uint64_t hash_host_memory_here(const uint8_t* source, size_t size, bool cached) {
    if (cached) return XXH3_64bits(source, size);
    // Small enough for the stack and for L1, large enough that the streaming copy runs whole lines.
    constexpr size_t kStep = 8192;
    alignas(64) uint8_t buffer[kStep];
    if (size <= kStep) {
        copy_from_uncached(buffer, source, size);
        return XXH3_64bits(buffer, size);
    }
    XXH3_state_t state;
    XXH3_INITSTATE(&state);
    XXH3_64bits_reset(&state);
    for (size_t at = 0; at < size; at += kStep) {
        const size_t step = size - at < kStep ? size - at : kStep;
        copy_from_uncached(buffer, source + at, step);
        XXH3_64bits_update(&state, buffer, step);
    }
    return XXH3_64bits_digest(&state);
}

}  // namespace
}  // namespace clastrace::capture
