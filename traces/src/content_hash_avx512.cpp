// SPDX-License-Identifier: Apache-2.0
// Compiled with -mavx512f (traces/CMakeLists.txt); run only where the CPU and OS have AVX-512F.
#include "content_hash.h"

// GCC 12 warns that xxhash's AVX-512 accumulate reads an uninitialized register
// (avx512fintrin.h, _mm512_undefined used as a don't-care operand): a known false positive.
#pragma GCC diagnostic ignored "-Wuninitialized"
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"

#define XXH_VECTOR XXH_AVX512
#define CONTENT_HASH_FUNCTION hash_content_avx512
#define CONTENT_KEY_FUNCTION content_key_avx512
#include "content_hash_kernel.inc"
