// SPDX-License-Identifier: Apache-2.0
// Where a whole trace file's records chunks lie, read straight from the chunk headers: for tests
// that damage or inspect one chunk's bytes.
#pragma once

#include "file_format.h"

#include <cstdint>
#include <vector>

namespace clastrace::traces::testing {

struct ChunkAt {
    uint64_t offset;
    format::ChunkHeader header;
};

// The records chunks in file order, up to the index chunk or the trailer.
inline std::vector<ChunkAt> records_chunks(const std::vector<uint8_t>& file) {
    namespace f = format;
    std::vector<ChunkAt> chunks;
    const auto fh = f::load<f::FileHeader>(file.data());
    for (uint64_t at = f::kFileHeaderSize + f::align8(fh.trace_header_size);
         at + f::kChunkHeaderSize <= file.size() - f::kTrailerSize;) {
        const auto h = f::load<f::ChunkHeader>(file.data() + at);
        if (h.kind == uint16_t(f::ChunkKind::kRecords)) chunks.push_back({at, h});
        if (h.kind == uint16_t(f::ChunkKind::kIndex)) break;
        at += f::kChunkHeaderSize + h.compressed_size;
    }
    return chunks;
}

}  // namespace clastrace::traces::testing
