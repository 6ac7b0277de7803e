// SPDX-License-Identifier: Apache-2.0
// The streams payload of a records chunk (docs/trace-format.md, "Streams payload"): the chunk's
// raw bytes as two zstd frames, the records with the contents' bytes cut out, and those bytes
// (whole contents in 4 byte planes). Records and vertex bytes compress better apart than
// interleaved; decoding gives back the very raw bytes a one-frame payload holds, so everything
// after decompression (frames, offsets in the index, deltas) is unchanged.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include <zstd.h>

#include "uninitialized_bytes.h"

namespace clastrace::traces::format {

// "CLTS": neither zstd's frame magic nor a skippable frame's, so a reader that knows only
// one-frame payloads finds no frame declaring the chunk's size and reports the chunk damaged.
inline constexpr uint32_t kStreamsMagic = 0x53544c43;
inline constexpr size_t kStreamsHeaderSize = 16;  // magic, two frame sizes, reserved 0
inline constexpr size_t kStreamsCutBytes = 12;    // u32 gap, u32 size, u32 layout
// Fewer raw bytes than any framed contents record takes (8 of frame, then at least a root
// offset and the vector's length): bounds the cut table a reader accepts.
inline constexpr size_t kMinContentsFrameBytes = 16;

// How a cut's bytes lie in the contents stream.
enum class CutLayout : uint32_t { kAsIs = 0, kBytePlanes = 4 };

// One content's bytes inside a records chunk's raw bytes, moved to the contents stream.
struct ContentCut {
    uint32_t offset = 0;  // in the chunk's raw bytes
    uint32_t size = 0;
    CutLayout layout = CutLayout::kAsIs;
};

// Whether whole contents look like 32-bit integers (indices, counts: most words non-zero, and
// 15 in 16 of them share their high byte), which byte planes store smaller. Not floats, whose
// repeats (vertices copied into cluster objects) zstd finds only while they are whole, nor
// bytes that are mostly zeros. Judged on at most 4096 words spread over the bytes.
bool planes_pay(const uint8_t* bytes, size_t size);

// Appends one zstd frame of `size` bytes at `bytes`, at `level` and `window_log` (0: what the
// level picks), to `out`. Returns an empty string or zstd's complaint. Every payload frame the
// writer makes goes through here.
std::string compress_frame(ZSTD_CCtx* cctx, const uint8_t* bytes, size_t size, int level,
                           int window_log, UninitializedBytes* out);

// Whether a chunk's payload is a streams payload (else one zstd frame).
bool is_streams_payload(const uint8_t* payload, size_t size);

// A records chunk as the writer builds it: already in its two streams, so that no pass over
// the chunk has to split its raw bytes (and no raw bytes are made unless the payload must be
// one frame after all).
struct SplitChunk {
    std::span<const uint8_t> records;   // the raw bytes with every cut left out
    std::span<const uint8_t> contents;  // the cuts' bytes in cut order, each in its layout
    // In raw order, offsets in the raw bytes; each starts at least kMinContentsFrameBytes after
    // the end of the one before (one cut per contents record, as readers expect).
    std::span<const ContentCut> cuts;
    size_t raw_size() const { return records.size() + contents.size(); }
};

// Compresses `chunk` as a streams payload into `out` (what it held is replaced). Returns an
// empty string or zstd's complaint.
std::string encode_split_chunk(ZSTD_CCtx* cctx, const SplitChunk& chunk, int zstd_level,
                               int zstd_window_log, UninitializedBytes* out);

// The raw bytes `chunk` stands for (cuts in byte planes laid back), into `raw`: for a chunk
// whose streams payload would exceed one frame's bound and is written as one frame.
void join_split_chunk(const SplitChunk& chunk, UninitializedBytes* raw);

// Compresses `raw` as a streams payload into `out`: `raw` split at `cuts`, then
// encode_split_chunk. (The writer splits as it frames records; tests and the fuzz target
// start from raw bytes.)
std::string encode_streams_payload(ZSTD_CCtx* cctx, const uint8_t* raw, size_t raw_size,
                                   std::span<const ContentCut> cuts, int zstd_level,
                                   int zstd_window_log, std::vector<uint8_t>* out);

// What is wrong with a streams payload, and where (bytes from the payload's start).
struct StreamsProblem {
    std::string what;  // empty: decoded
    uint64_t at = 0;
    explicit operator bool() const { return !what.empty(); }
};

// Decodes a streams payload into exactly `raw_size` bytes at `out`.
StreamsProblem decode_streams_payload(ZSTD_DCtx* dctx, const uint8_t* payload, size_t size,
                                      uint8_t* out, size_t raw_size);

}  // namespace clastrace::traces::format
