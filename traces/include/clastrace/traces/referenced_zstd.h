// SPDX-License-Identifier: Apache-2.0
// The peer a trace's size is judged against (issue 23): plain zstd, at the trace's level, over
// the bytes its snapshots reference, concatenated in trace order, as one stream (what a capture
// that stored every snapshot and compressed the lot, knowing nothing of the data, would write).
// The capture bench and `clastrace info --vs-zstd` print the trace's size against it.
#pragma once

#include <clastrace/traces/trace_error.h>
#include <clastrace/traces/trace_reader.h>

#include <cstdint>
#include <string>

namespace clastrace::traces {

struct ReferencedZstd {
    uint64_t snapshots = 0;         // snapshots read (inputs and outputs of every record)
    uint64_t referenced_bytes = 0;  // their sizes summed
    uint64_t zstd_bytes = 0;        // plain zstd of those bytes
    int zstd_level = 0;
};

// Reads the trace at `path` once and compresses its referenced bytes at `zstd_level` (the
// trace's own level when 0 is given and the header names one, else 3), keeping the last 256 MiB
// of contents to hand (older ones are read again with read_contents). Costs zstd over every
// referenced byte: about 0.3 s per 100 MB at level 3 on one core.
TraceError referenced_zstd(const std::string& path, int zstd_level,
                           const TraceReaderOptions& options, ReferencedZstd* out);

}  // namespace clastrace::traces
