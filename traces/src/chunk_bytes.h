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

namespace clastrace::traces::reader {

// The reader holds at most one buffer above this (the chunk being read or the one
// read_contents needs), so its memory stays near one chunk of kMaxChunkRawBytes.
constexpr uint32_t kBigBufferBytes = 32u << 20;

// Bytes that are written before they are read (decompressed chunks, compressed payloads):
// growing them leaves the new bytes undefined instead of zeroing them, a pass over every
// chunk's bytes that decompression then overwrites.
template <class T>
struct UninitializedAllocator : std::allocator<T> {
    template <class U>
    struct rebind {
        using other = UninitializedAllocator<U>;
    };
    UninitializedAllocator() = default;
    template <class U>
    UninitializedAllocator(const UninitializedAllocator<U>&) noexcept {}
    template <class U>
    void construct(U* p) noexcept(std::is_nothrow_default_constructible_v<U>) {
        ::new (static_cast<void*>(p)) U;
    }
    template <class U, class... Args>
    void construct(U* p, Args&&... args) {
        ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
    }
};
using ChunkBytes = std::vector<uint8_t, UninitializedAllocator<uint8_t>>;

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
