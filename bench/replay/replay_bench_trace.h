// SPDX-License-Identifier: Apache-2.0
// Traces for the replay benchmark, written with the TraceWriter the way a capture of a
// clustered-geometry renderer would record them: per frame, one submission that uploads
// cluster infos, builds CLAS batches of 64-128-triangle clusters into implicit
// destinations (one scratch buffer reused behind barriers), builds a BLAS over them, and
// every 4th frame moves the clusters into a streamed buffer that is destroyed and
// re-created at a new address every 16 frames. Two frames are in flight (fence waits).
#pragma once

#include <cstdint>
#include <string>

namespace clastrace::bench {

struct BenchTraceShape {
    uint64_t target_ops = 1000;  // stop after the frame that reaches this many ops
    uint32_t clusters_per_build = 32;
    uint32_t builds_per_frame = 2;
    uint32_t cluster_pool = 256;  // distinct cluster geometries the frames pick from
    // false: a frame's CLAS builds reuse the scratch buffer with no barrier between them (a
    // write-after-write hazard per frame, for tests).
    bool scratch_barriers = true;
    uint64_t seed = 1;
};

struct BenchTraceStats {
    uint64_t ops = 0;  // cluster ops + other commands (copies, fills, updates, barriers)
    uint64_t cluster_ops = 0;
    uint64_t commands = 0;
    uint64_t submissions = 0;
    uint64_t file_bytes = 0;
    // The largest submission: its records' bytes plus the bytes of every memory snapshot
    // its commands carry (what one submission can bring into the replay at once).
    uint64_t largest_submission_bytes = 0;
    uint64_t buffers_destroyed = 0;
    uint64_t contents = 0;  // distinct memory contents stored (the reader indexes each)
};

// Writes the trace to `path`; throws std::runtime_error on a write error.
BenchTraceStats write_bench_trace(const std::string& path, const BenchTraceShape& shape);

}  // namespace clastrace::bench
