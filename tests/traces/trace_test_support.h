// SPDX-License-Identifier: Apache-2.0
// Shared helpers of the trace tests: a device header, one record of every kind, and
// small file utilities.
#pragma once

#include <clastrace/traces/trace_reader.h>
#include <clastrace/traces/trace_writer.h>

#include <cstdint>
#include <map>
#include <string>
#include <vector>

namespace clastrace::traces::testing {

fbs::TraceHeaderT test_header();

// One record of every kind except MemoryContents (which the writer makes), with
// non-default values in their fields. Snapshots refer to contents added to `writer`.
std::vector<fbs::RecordT> one_of_every_kind(TraceWriter& writer);

// One range a frame snapshots: `size` bytes at `bytes`, of buffer `buffer` at address
// 0x1000 * buffer.
struct SnapshotPiece {
    uint64_t buffer;
    const void* bytes;
    size_t size;
};
// Appends a cluster build whose inputs snapshot `pieces`, in order, and records each snapshot's
// bytes by its key in `bytes_by_key`; returns the keys in order.
std::vector<uint64_t> append_build_snapshotting(
    TraceWriter& writer, const std::vector<SnapshotPiece>& pieces,
    std::map<uint64_t, std::vector<uint8_t>>& bytes_by_key);

// A fresh path under the test temp dir (removed by the caller or left for inspection).
std::string temp_path(const std::string& name);

std::vector<uint8_t> read_file(const std::string& path);
void write_file(const std::string& path, const std::vector<uint8_t>& bytes);

// Everything a reader yields, for comparisons.
struct ReadResult {
    bool opened = false;
    TraceError open_error;
    std::vector<fbs::RecordT> records;  // unpacked, MemoryContents included
    std::vector<TraceError> damage;
    uint64_t damage_count = 0;
    bool has_index = false;
    TraceReadStats stats;  // at the end
};
// With content keys verified, unless `options` say otherwise.
ReadResult read_all(const std::string& path);
ReadResult read_all(const std::string& path, const TraceReaderOptions& options);
ReadResult read_all_memory(const std::vector<uint8_t>& bytes);
ReadResult read_all_memory(const std::vector<uint8_t>& bytes, const TraceReaderOptions& options);
// Everything `reader` yields from where it stands; `error` is the open error when it is null.
ReadResult drain(std::unique_ptr<TraceReader> reader, const TraceError& error);

// Writes a trace of `submissions` frames with realistic contents (some repeated) and
// chunks of `chunk_bytes`. Returns the records appended (MemoryContents excluded).
std::vector<fbs::RecordT> write_frames_trace(const std::string& path, int submissions,
                                             uint32_t chunk_bytes, TraceWriterOptions options = {});

std::string describe(const std::vector<TraceError>& damage);

}  // namespace clastrace::traces::testing
