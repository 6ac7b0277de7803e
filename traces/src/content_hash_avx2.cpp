// SPDX-License-Identifier: Apache-2.0
// Compiled with -mavx2 (traces/CMakeLists.txt); run only where the CPU has AVX2.
#include "content_hash.h"

#define XXH_VECTOR XXH_AVX2
#define CONTENT_HASH_FUNCTION hash_content_avx2
#define CONTENT_KEY_FUNCTION content_key_avx2
#include "content_hash_kernel.inc"
