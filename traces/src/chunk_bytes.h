// SPDX-License-Identifier: Apache-2.0
// The trace reader's chunk buffers: bytes that decompression overwrites (never zeroed first),
// sized to the chunk they hold, and the per-thread set of a compressed payload and zstd context.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <new>
#include <type_traits>
#include <utility>
#include <vector>

#include <zstd.h>

#include "clastrace/common/uninitialized_allocator.h"

namespace clastrace::traces::reader {

// The reader holds at most one buffer above this (the chunk being read or the one
// read_contents needs), so its memory stays near one chunk of kMaxChunkRawBytes.
constexpr uint32_t kBigBufferBytes = 32u << 20;

// Decompressed chunks and compressed payloads: written before they are read, never zeroed.
using ChunkBytes = common::UninitializedBytes;

// Frees a buffer whose capacity a big chunk left behind, so it does not linger.
inline void release_if_big(ChunkBytes& buffer, size_t needed = 0) {
    if (buffer.capacity() > kBigBufferBytes && buffer.capacity() > 2 * needed)
        ChunkBytes().swap(buffer);
}

// Sizes a buffer to n bytes, grown to exactly n: vector::resize grows to twice the old size, so
// a chunk of 3.1 MB after one of 3 MB held 6 MB (replay's peak memory was four such buffers).
inline void resize_exact(ChunkBytes& buffer, size_t n) {
    if (n > buffer.capacity()) {
        buffer.clear();  // nothing to move to the new buffer
        buffer.reserve(n);
    }
    buffer.resize(n);
}

// What one thread needs to read a chunk: the reader uses one set on its own thread
// and one on the read-ahead task, so decompressing chunk n+1 overlaps the checks of chunk n.
struct ChunkDecoder {
    ChunkBytes compressed;
    ZSTD_DCtx* dctx = ZSTD_createDCtx();
    ChunkDecoder() = default;
    ChunkDecoder(const ChunkDecoder&) = delete;
    ChunkDecoder& operator=(const ChunkDecoder&) = delete;
    ~ChunkDecoder() { ZSTD_freeDCtx(dctx); }
};

}  // namespace clastrace::traces::reader
