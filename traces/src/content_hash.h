// SPDX-License-Identifier: Apache-2.0
// The trace writer's hashing of a content given in pieces, run with the widest vector unit the
// CPU has: XXH3's values do not depend on it, its speed does (about 1.5x from SSE2 to AVX-512
// on the development machine).
//
// Kernel files include this header and xxhash.h only: code compiled for AVX2 or AVX-512 must
// not emit any inline function the linker could pick for the rest of the program.
#pragma once

#include <clastrace/traces/content_piece.h>

#include <cstddef>
#include <cstdint>

namespace clastrace::traces {

struct ContentHashes {
    uint64_t fingerprint_low, fingerprint_high;  // XXH3-128: the writer's repeat finder
    uint64_t key_seed0;  // XXH3-64 at seed 0: format::content_key before masking
};

// One pass over the pieces' concatenation gives both: XXH3's 64- and 128-bit variants share
// one streaming state and differ only in the digest.
ContentHashes hash_content(const ContentPiece* pieces, size_t count);
// XXH3-64 at `seed` over the concatenation (a key after a collision at the seeds before).
uint64_t content_key_of(const ContentPiece* pieces, size_t count, uint64_t seed);

struct ContentHashKernel {
    const char* isa;  // "sse2" (or the compiler's baseline off x86-64), "avx2", "avx512"
    ContentHashes (*hash)(const ContentPiece*, size_t);
    uint64_t (*key)(const ContentPiece*, size_t, uint64_t seed);
};
// The kernels this CPU can run, baseline first; hash_content uses the last.
const ContentHashKernel* content_hash_kernels(size_t* count);

namespace detail {
ContentHashes hash_content_baseline(const ContentPiece*, size_t);
uint64_t content_key_baseline(const ContentPiece*, size_t, uint64_t);
ContentHashes hash_content_avx2(const ContentPiece*, size_t);
uint64_t content_key_avx2(const ContentPiece*, size_t, uint64_t);
ContentHashes hash_content_avx512(const ContentPiece*, size_t);
uint64_t content_key_avx512(const ContentPiece*, size_t, uint64_t);
}  // namespace detail

}  // namespace clastrace::traces
