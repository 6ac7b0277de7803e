// SPDX-License-Identifier: Apache-2.0
// The compiler's baseline vector unit (SSE2 on x86-64).
#include "content_hash.h"

#define CONTENT_HASH_FUNCTION hash_content_baseline
#define CONTENT_KEY_FUNCTION content_key_baseline
#include "content_hash_kernel.inc"
