// SPDX-License-Identifier: Apache-2.0
// Writes a .clt trace: records go into chunks that background threads compress and append in
// order, so the caller only pays for building records. Memory is bounded by
// (max_chunks_in_flight + compressor_threads + 1) chunks, each in two recycled buffers (records,
// contents) that keep what they grew to, so up to twice chunk_raw_bytes a chunk; plus about
// 150 bytes per distinct content (its key, size, 128-bit fingerprint, the fingerprint's way
// back to the key, and place for the index), plus the snapshot ranges' last bytes kept as delta
// bases (delta_base_bytes).
//
// Errors are sticky: once a write fails (disk full, I/O error) every later call and
// finish() return that error; nothing is lost silently.
//
// Every string the writer stores (the header's names, labels, finding texts) is UTF-8: bytes
// that are not become U+FFFD as they are written (utf8_text.h), whoever built the record.
#pragma once

#include <clastrace/traces/content_piece.h>
#include <clastrace/traces/trace_error.h>
#include <clastrace/traces/trace_generated.h>

#include <cstddef>
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

namespace clastrace::traces {

struct TraceWriterOptions {
    uint32_t chunk_raw_bytes = 4u << 20;  // a chunk is sealed once its records reach this size
    int zstd_level = 3;
    // zstd's window (log2 bytes) for records chunks; 0: what the level picks (2 MiB at level 3,
    // half a 4 MiB chunk). Readers need no setting up to 2^27 (zstd's default decoder limit).
    int zstd_window_log = 0;
    uint32_t max_chunks_in_flight = 2;  // sealed chunks waiting for a compression thread
    // Threads compressing sealed chunks, each its own chunk (zstd at one level is one core's
    // work per chunk: more threads write faster where cores are free, the file is the same).
    // Each holds one chunk besides those in flight.
    uint32_t compressor_threads = 1;
    bool sync_on_finish = true;  // fsync before finish() reports success
    // Bits of the content hash kept. 64 for real traces; tests lower it to force collisions.
    unsigned content_hash_bits = 64;
    // Nice value of the compression thread (Linux: per thread; 0 leaves it as created). A
    // capture runs it at a lower priority than the application, so compression takes idle
    // cores rather than the application's.
    int compressor_nice = 0;
    // Runs the compression thread in Linux's idle scheduling class (SCHED_IDLE): it gets a core
    // only when no normal thread wants it, so a capture's compression never delays the threads
    // of the application. Where the class is refused, compressor_nice applies instead.
    bool compressor_idle_class = false;
    // The CPUs the compression thread may run on (Linux, 0-based); empty: those of the thread
    // creating the writer. Best effort: a set the kernel refuses leaves it where it was created.
    std::vector<unsigned> compressor_cpus;
    // Delta storage: new contents of a snapshot range (snapshot()'s buffer, offset, address and
    // size) are stored XOR the previous contents of that range, so the bytes a frame did not
    // change are zeros (a MemoryContentsDelta record, format 1.6). The writer keeps each range's
    // last bytes, at most delta_base_bytes in all (least recently used ranges are forgotten
    // first; their next contents are stored whole), so its memory stays bounded.
    // delta_contents = false writes what readers older than 1.6 read whole.
    bool delta_contents = true;
    uint64_t delta_base_bytes = uint64_t{64} << 20;
    // Deltas laid out in 4 byte planes (MemoryContentsDelta.byte_planes 4), which groups the
    // unchanged high bytes of 32-bit values that changed a little.
    bool delta_byte_planes = true;
    // Longest chain of deltas before contents are stored whole again: read_contents of one
    // content far from the scan resolves at most this many bases. 0: no limit.
    uint32_t delta_chain_limit = 256;
    // Records chunks as a streams payload (docs/trace-format.md): the records and the contents'
    // bytes in two zstd frames, which compress better apart. Off: one frame, which readers
    // older than this option read.
    bool content_streams = true;
    // In a streams payload, contents stored whole that look like 32-bit integers (indices,
    // counts; format::planes_pay) go in 4 byte planes, as deltas do, which groups their
    // high bytes. Off: every content as it is.
    bool whole_content_planes = true;
};

struct TraceWriterStats {
    uint64_t records = 0;
    uint64_t submissions = 0;
    uint64_t chunks = 0;            // record chunks written so far (not counting the index)
    uint64_t raw_bytes = 0;         // record bytes before compression, framing included
    uint64_t compressed_bytes = 0;  // chunk payload bytes after compression
    uint64_t contents_stored = 0;   // distinct MemoryContents records written
    uint64_t contents_bytes_stored = 0;
    uint64_t contents_deduplicated = 0;  // add_contents calls answered by an existing record
    uint64_t contents_bytes_deduplicated = 0;
    uint64_t hash_collisions = 0;        // distinct bytes whose first-choice key was taken
    uint64_t contents_delta_stored = 0;  // of contents_stored: stored XOR an earlier content
    uint64_t contents_delta_bytes = 0;
    // Where the writer's time goes (nanoseconds; wall clock unless named CPU).
    uint64_t contents_ns = 0;        // add_contents: hashing, dedup lookup, framing new contents
    uint64_t compress_ns = 0;        // zstd on the compression thread(s)
    uint64_t file_write_ns = 0;      // writev of compressed chunks
    uint64_t compressor_cpu_ns = 0;  // CPU time of the compression thread(s)
    uint64_t append_blocked_ns = 0;  // callers waiting for room in the compression queue
    uint64_t flush_wait_ns = 0;      // flush()/finish() waiting for the compression thread(s)
    bool compressor_placed = false;  // the compression thread runs on options.compressor_cpus
};

class TraceWriter {
public:
    // Writes a new trace at `path` under the output-file rule (output_file.h): a regular file
    // is locked and written in place, so a killed writer still leaves what it flushed there;
    // another writer holding the lock is refused. The writer fills header.capture's chunk
    // size, zstd level and hash bits from `options`.
    // Returns nullptr with *error set when the file cannot be created or options are bad.
    static std::unique_ptr<TraceWriter> create(const std::string& path,
                                               const fbs::TraceHeaderT& header,
                                               const TraceWriterOptions& options,
                                               TraceError* error);
    // The same on `fd`, already opened (and locked) by open_output_in_place or adopt_output for
    // `path`: the writer takes it over (closes it, on failure too) and empties a regular file
    // before writing the header.
    static std::unique_ptr<TraceWriter> create_on(int fd, const std::string& path,
                                                  const fbs::TraceHeaderT& header,
                                                  const TraceWriterOptions& options,
                                                  TraceError* error);
    ~TraceWriter();  // without finish(): stops the thread, leaves a file without index
    TraceWriter(const TraceWriter&) = delete;
    TraceWriter& operator=(const TraceWriter&) = delete;

    // Stores `bytes` once: on the first call for a byte string a MemoryContents record is
    // written; later calls with equal bytes only return its key in *hash.
    TraceError add_contents(const void* bytes, size_t size, uint64_t* hash);

    // The same for the concatenation of `pieces` (adjacent ranges read separately): equal bytes
    // get the same key however they were cut, and a repeat is hashed where it lies, uncopied.
    TraceError add_contents(std::span<const ContentPiece> pieces, uint64_t* hash);

    // add_contents, then describes the snapshot for a command's inputs/outputs. New contents
    // may be stored as a delta against the range's previous contents (delta_contents).
    TraceError snapshot(uint64_t buffer, uint64_t offset, uint64_t address, const void* bytes,
                        size_t size, fbs::MemorySnapshot* out);
    TraceError snapshot(uint64_t buffer, uint64_t offset, uint64_t address,
                        std::span<const ContentPiece> pieces, fbs::MemorySnapshot* out);

    // Appends one record. MemoryContents must go through add_contents; a QueueSubmit's
    // submission_index must equal next_submission_index().
    TraceError append(const fbs::RecordT& record);
    TraceError append(
        const fbs::Record* record);  // any verified Record (e.g. copied from a reader)
    TraceError append_record_bytes(const uint8_t* data,
                                   size_t size);  // a finished Record FlatBuffer

    uint64_t next_submission_index() const;

    // Seals the chunk being filled and returns once the compression thread has written every
    // sealed chunk, so what was appended so far survives the process being killed (a reader
    // of the unfinished file gets it back; no fsync: a power loss is not covered). A capture
    // calls it periodically; each call ends a chunk, so calling it often costs compression.
    TraceError flush();

    // Seals the last chunk, waits for the compression thread, writes the index chunk and
    // trailer, and (by option) fsyncs. The first error met anywhere is returned.
    TraceError finish();

    TraceWriterStats stats() const;

    struct Impl;

private:
    explicit TraceWriter(std::unique_ptr<Impl> impl);
    std::unique_ptr<Impl> impl_;
};

}  // namespace clastrace::traces
