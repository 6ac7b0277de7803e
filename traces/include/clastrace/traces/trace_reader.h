// SPDX-License-Identifier: Apache-2.0
// Reads a .clt trace chunk by chunk with bounded work and memory: one decompressed chunk,
// one more of at most 16 MiB read ahead (on a task, so decompression overlaps the caller),
// one for read_contents (at most one of the two above 32 MiB at a time), the index (bounded
// by what the file's size makes plausible), about 64 bytes per distinct content, and the
// real bytes of recent contents kept as bases of delta contents (64 MiB at most for the
// caller's thread and 64 MiB for the read-ahead task, which decodes the deltas of the chunk it
// reads ahead; the two share the bytes they both keep), the real bytes read_contents handed
// out (16 MiB, so a content read again costs a lookup); all the bytes it decompresses are
// bounded by a budget relative to the file's size. Every record is checked by the FlatBuffers
// verifier before it is handed out. Damage does not stop reading: it is listed in damage() and
// the reader continues with the next intact chunk.
#pragma once

#include <clastrace/traces/trace_error.h>
#include <clastrace/traces/trace_generated.h>

#include <cstddef>
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

namespace clastrace::traces {

class ByteSource;  // traces/src/byte_source.h

// One record, valid until the next call to next(), seek_to_submission() or read_contents().
struct RecordView {
    const fbs::Record* record = nullptr;
    fbs::RecordBody kind = fbs::RecordBody::NONE;
    const uint8_t* bytes = nullptr;  // the Record FlatBuffer
    uint32_t size = 0;
    uint64_t chunk_offset = 0;  // file offset of the chunk holding it
    uint32_t chunk_number = 0;
    uint32_t raw_offset = 0;  // offset of its frame in the chunk's decompressed bytes
};

struct TraceReadStats {
    uint64_t file_size = 0;
    uint64_t chunks_read = 0;  // record chunks that passed their checksums
    uint64_t chunks_damaged = 0;
    uint64_t raw_bytes = 0;         // decompressed bytes of the chunks read
    uint64_t compressed_bytes = 0;  // their compressed payload bytes
    uint64_t records = 0;           // records handed out
    uint64_t records_damaged = 0;   // records skipped because they failed a check
    uint64_t bytes_skipped = 0;     // bytes passed over while looking for the next chunk
    uint64_t raw_bytes_decompressed =
        0;  // every byte decompressed (read-ahead, read_contents, index included)
    uint64_t raw_budget =
        0;  // the limit on raw_bytes_decompressed (TraceReaderOptions::max_raw_bytes)
    // Delta contents XORed ahead of their records' checks (TraceReaderOptions::
    // decode_deltas_ahead: on the read-ahead task for the chunks it reads), whose real bytes the
    // caller's thread only copied in.
    uint64_t deltas_decoded_ahead = 0;
    // What the chunk buffers hold now (their capacity): decompressed and compressed bytes of
    // the chunk being read, of the one read ahead and of read_contents' chunk. The index and
    // the real bytes kept as delta bases are not counted.
    uint64_t chunk_buffer_bytes = 0;
    // Bytes of fresh buffers taken for contents' real bytes (delta bases, on both threads); a
    // buffer no cache holds any more is filled again instead, so a frame loop's stop growing.
    uint64_t real_bytes_allocated = 0;
};

// Speed/accuracy knob (bench/traces measures it). The chunk checksums always prove the
// bytes are what the writer wrote, so no flipped bit gets through either way; recomputing
// every content's key additionally proves the writer keyed them honestly, at the cost of
// hashing every stored byte once more (about 10% of read time). Off by default;
// `clastrace info`, `replay` and `analyze` turn it on so that all three give one verdict.
struct TraceReaderOptions {
    bool verify_content_keys = false;
    // Bytes the reader may decompress in all, so that a small file of chunks that inflate
    // enormously (256 MiB of zeros compress to 8 KiB) costs seconds, not minutes. Once the
    // next chunk would pass it the reader stops, with length_out_of_range damage.
    // 0: default_raw_budget(file size), far above what real traces inflate to (the samples
    // about 4x, the capture bench's frames of barely changing vertices 45x; replay's
    // read_contents decompresses some chunks more than once).
    uint64_t max_raw_bytes = 0;
    // Delta contents of a chunk read ahead are XORed on the read-ahead task, and the caller's
    // thread takes the result once the record passed its checks and the task's base is the
    // one it would use. False: every delta is decoded on the caller's thread (the tests compare
    // the two; records, bytes and damage are the same).
    bool decode_deltas_ahead = true;
};

inline constexpr uint64_t kRawBudgetFloorBytes = uint64_t{4} << 30;
inline constexpr uint64_t kRawBudgetPerFileByte = 1024;
// max(4 GiB, 1024 x the file size): zeros decompress at about 2.5 GB/s, so about 0.4 s per MB,
// and at most about 1.7 s for a small file. The floor is 4 GiB because a real capture of
// barely changing frames (120 frames of the traceable rooms on lavapipe: 1.07 GB raw) can
// inflate past 1024 times a file of a few hundred KB.
uint64_t default_raw_budget(uint64_t file_size);

class TraceReader {
public:
    // Fails (nullptr, *error) only when nothing can be read: unopenable or empty file,
    // wrong magic, newer major version. Lesser damage goes to damage().
    static std::unique_ptr<TraceReader> open(const std::string& path, TraceError* error,
                                             const TraceReaderOptions& options = {});
    // Reads from memory that must outlive the reader; `name` is used in messages.
    static std::unique_ptr<TraceReader> open_memory(const uint8_t* data, size_t size,
                                                    const std::string& name, TraceError* error,
                                                    const TraceReaderOptions& options = {});
    // Reads from `src` (traces/src/byte_source.h), which open() and open_memory() make; the
    // tests give sources that fail on purpose, on the read-ahead thread or on the caller's.
    static std::unique_ptr<TraceReader> open_source(std::unique_ptr<ByteSource> src,
                                                    const std::string& name, TraceError* error,
                                                    const TraceReaderOptions& options = {});
    ~TraceReader();
    TraceReader(const TraceReader&) = delete;
    TraceReader& operator=(const TraceReader&) = delete;

    uint16_t version_major() const;
    uint16_t version_minor() const;
    // The format version this library writes (a file's minor may be lower: older, still read).
    static uint16_t current_version_minor();
    // From format 1.9 on, the capture layer's own GpuTimestamp records take no command index
    // (findings, DeviceAddressWrites and execute_command_index count the application's commands
    // only); a 1.8 or older file counted them, and is read with its own numbering.
    bool timestamps_take_command_indices() const;
    // The TraceHeader, or nullptr when it is damaged (see damage()).
    const fbs::TraceHeader* header() const;

    // True when the file ends with an intact index (it was finished).
    bool has_index() const;
    // Submissions listed in the index (0 without index).
    uint64_t indexed_submission_count() const;

    // Next intact record in file order; false at the end of the records.
    bool next(RecordView* out);

    // Positions the reader so that next() returns the QueueSubmit with this
    // submission_index. Uses the index when present, else scans from the start.
    TraceError seek_to_submission(uint64_t submission_index);

    // Copies the bytes of the contents with this hash (defined anywhere in the file the
    // reader has seen or the index lists). Delta contents (MemoryContentsDelta, format 1.7)
    // come back as their real bytes: the chain of bases is resolved (a base must precede its
    // delta), and each result is checked against its key. next() hands deltas out decoded.
    TraceError read_contents(uint64_t hash, std::vector<uint8_t>* out);
    // read_contents without the copy: *out views the real bytes, which the reader holds until
    // the next read_contents_view (replay lays a content in at every snapshot naming it).
    TraceError read_contents_view(uint64_t hash, std::span<const uint8_t>* out);

    // Every problem found so far, in the order found (at most 1000 kept; see damage_count()).
    const std::vector<TraceError>& damage() const;
    uint64_t damage_count() const;

    const TraceReadStats& stats() const;

    struct Impl;

private:
    explicit TraceReader(std::unique_ptr<Impl> impl);
    std::unique_ptr<Impl> impl_;
};

}  // namespace clastrace::traces
