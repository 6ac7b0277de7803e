// SPDX-License-Identifier: Apache-2.0
#include "file_format.h"

#define XXH_INLINE_ALL
#include <xxhash.h>

namespace clastrace::traces::format {

uint64_t checksum(const void* data, size_t size) { return XXH3_64bits(data, size); }

uint64_t file_header_checksum(const FileHeader& h, const uint8_t* trace_header, size_t size) {
    XXH3_state_t state;
    XXH3_64bits_reset(&state);
    XXH3_64bits_update(&state, &h, offsetof(FileHeader, checksum));
    XXH3_64bits_update(&state, trace_header, size);
    return XXH3_64bits_digest(&state);
}

uint64_t chunk_header_checksum(const ChunkHeader& h) {
    return XXH3_64bits(&h, offsetof(ChunkHeader, header_checksum));
}

uint64_t trailer_checksum(const Trailer& t) { return XXH3_64bits(&t, offsetof(Trailer, checksum)); }

ChunkHeader sealed_chunk_header(ChunkKind kind, uint32_t chunk_number, uint32_t record_count,
                                uint64_t first_submission, uint32_t raw_size,
                                const void* compressed, uint32_t compressed_size) {
    ChunkHeader h{};
    h.magic = kChunkMagic;
    h.kind = static_cast<uint16_t>(kind);
    h.chunk_number = chunk_number;
    h.record_count = record_count;
    h.raw_size = raw_size;
    h.compressed_size = compressed_size;
    h.first_submission = first_submission;
    h.payload_checksum = checksum(compressed, compressed_size);
    h.header_checksum = chunk_header_checksum(h);
    return h;
}

Trailer sealed_trailer(uint64_t index_offset, uint64_t trailer_offset) {
    Trailer t{};
    std::memcpy(t.magic, kTrailerMagic, sizeof t.magic);
    t.index_offset = index_offset;
    t.trailer_offset = trailer_offset;
    t.checksum = trailer_checksum(t);
    return t;
}

uint64_t content_key(const void* data, size_t size, uint64_t seed, unsigned bits) {
    uint64_t h = XXH3_64bits_withSeed(data, size, seed);
    return bits >= 64 ? h : (h & ((uint64_t{1} << bits) - 1));
}

}  // namespace clastrace::traces::format
