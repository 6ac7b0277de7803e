// SPDX-License-Identifier: Apache-2.0
// hash_host_memory with AVX2 (built with -mavx2 where the compiler targets x86-64; called only
// where the processor has AVX2): XXH3's long inputs in half the instructions of its SSE2 code,
// for the host-write watch's hashes of every mapped input, on the application's thread and in
// the pause.
#include "host_memory_hash.h"

namespace clastrace::capture {

uint64_t hash_host_memory_avx2(const uint8_t* source, size_t size, bool cached) {
    return hash_host_memory_here(source, size, cached);
}

}  // namespace clastrace::capture
