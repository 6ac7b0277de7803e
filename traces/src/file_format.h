// SPDX-License-Identifier: Apache-2.0
// Byte layout of a .clt file (docs/trace-format.md draws it). Internal: readers and
// writers of other projects go through TraceReader/TraceWriter, never these structs.
#pragma once

#include <bit>
#include <cstddef>
#include <cstdint>
#include <cstring>

namespace clastrace::traces::format {

static_assert(std::endian::native == std::endian::little,
              "the .clt layout is little-endian and is read with memcpy");

inline constexpr char kFileMagic[8] = {'C', 'L', 'A', 'S', 'T', 'R', 'C', '\0'};
inline constexpr uint16_t kVersionMajor = 1;         // bumped when old readers would misread
inline constexpr uint16_t kVersionMinor = 9;         // bumped for additive changes
inline constexpr uint16_t kFirstStreamsMinor = 8;    // streams payloads (chunk_streams.h)
inline constexpr uint32_t kChunkMagic = 0x4b434c43;  // "CLCK"
inline constexpr char kTrailerMagic[8] = {'C', 'L', 'T', 'I', 'N', 'D', 'E', 'X'};

inline constexpr size_t kFileHeaderSize = 32;
inline constexpr size_t kChunkHeaderSize = 48;
inline constexpr size_t kTrailerSize = 32;
inline constexpr size_t kRecordFrameSize = 8;  // u32 size + u32 kind, then the FlatBuffer

// Limits checked before anything is allocated: a hostile length field costs at most these.
inline constexpr uint32_t kMaxTraceHeaderBytes = 16u << 20;
inline constexpr uint32_t kMaxChunkRawBytes = 256u << 20;
inline constexpr uint32_t kMaxIndexRawBytes = 1024u << 20;  // big traces index millions of contents
inline constexpr uint32_t kMaxRecordBytes = kMaxChunkRawBytes - kRecordFrameSize;

enum class ChunkKind : uint16_t { kRecords = 1, kIndex = 2 };

// File header, offset 0. The TraceHeader FlatBuffer follows, padded to 8 bytes.
struct FileHeader {
    char magic[8];
    uint16_t version_major;
    uint16_t version_minor;
    uint32_t trace_header_size;  // bytes of the TraceHeader FlatBuffer
    uint64_t flags;              // reserved, 0
    uint64_t checksum;           // xxh3-64 of bytes [0, 24) and the TraceHeader bytes
};
static_assert(sizeof(FileHeader) == kFileHeaderSize);

struct ChunkHeader {
    uint32_t magic;
    uint16_t kind;
    uint16_t reserved;
    uint32_t chunk_number;  // 0, 1, 2 ... in file order; the index chunk continues the count
    uint32_t record_count;
    uint32_t raw_size;
    uint32_t compressed_size;
    uint64_t first_submission;  // QueueSubmit records before this chunk
    uint64_t payload_checksum;  // xxh3-64 of the compressed payload
    uint64_t header_checksum;   // xxh3-64 of bytes [0, 40) of this header
};
static_assert(sizeof(ChunkHeader) == kChunkHeaderSize);
static_assert(offsetof(ChunkHeader, header_checksum) == 40);

struct Trailer {
    char magic[8];
    uint64_t index_offset;    // offset of the index chunk's header
    uint64_t trailer_offset;  // offset of this trailer (= file size - 32)
    uint64_t checksum;        // xxh3-64 of bytes [0, 24)
};
static_assert(sizeof(Trailer) == kTrailerSize);

constexpr uint64_t align8(uint64_t n) { return (n + 7) & ~uint64_t{7}; }

uint64_t checksum(const void* data, size_t size);
uint64_t file_header_checksum(const FileHeader& h, const uint8_t* trace_header, size_t size);
uint64_t chunk_header_checksum(const ChunkHeader& h);
uint64_t trailer_checksum(const Trailer& t);

// A chunk header for `compressed`, the zstd payload of `raw_size` bytes, with both checksums
// filled in: what the writer writes, and what a test or bench crafting a file writes.
ChunkHeader sealed_chunk_header(ChunkKind kind, uint32_t chunk_number, uint32_t record_count,
                                uint64_t first_submission, uint32_t raw_size,
                                const void* compressed, uint32_t compressed_size);
// The trailer at `trailer_offset` of a file whose index chunk starts at `index_offset`.
Trailer sealed_trailer(uint64_t index_offset, uint64_t trailer_offset);

// Content key: xxh3-64 of the bytes with `seed`, keeping the low `bits` bits.
uint64_t content_key(const void* data, size_t size, uint64_t seed, unsigned bits);

template <class T>
T load(const uint8_t* p) {
    T v;
    std::memcpy(&v, p, sizeof v);
    return v;
}

}  // namespace clastrace::traces::format
