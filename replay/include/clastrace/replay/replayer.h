// SPDX-License-Identifier: Apache-2.0
// Replayer: re-executes a captured trace on the built-in engine, in queue order.
//
// For every submitted command it lays the command's captured memory snapshots into one
// MemoryImage, executes cluster builds with engine::execute (one ObjectDirectory for the
// whole replay, so later commands see earlier results), applies copies/fills/updates to
// the image, and feeds every access, barrier, event, semaphore, fence and host access to
// the SyncModel. Outputs the capture recorded are compared with the engine's: sizes side
// by side always, bytes exactly when the trace was made by clastrace's own engine.
//
// Captured object addresses (dstAddressesArray outputs) are translated to the addresses
// the engine rebuilt the objects at, wherever the spec says a value is an object address:
// clusterReferences arrays, move sources, template addresses.
#pragma once

#include <cstdint>
#include <functional>
#include <limits>
#include <string>

#include "clastrace/replay/replay_observer.h"
#include "clastrace/replay/replay_report.h"

namespace clastrace::traces {
class TraceReader;
}

namespace clastrace::replay {

struct ReplayProgress {
    uint64_t bytes_read = 0;  // file offset of the chunk being replayed
    uint64_t file_size = 0;
    uint64_t records = 0;
    uint64_t commands = 0;
};

// The arithmetic of the engine's traversal for ray checks (engine::TraversalMode).
enum class RayCheckTraversal : uint8_t {
    kCapturingDevice,  // the capturing device's: float32 (every driver that answers ray checks
                       // traces in float32: NVIDIA's, lavapipe's)
    kFloat32,
    kDouble,
};

struct ReplayOptions {
    bool check_hazards = true;
    // With check_hazards: consumers (rays, ray-query dispatches and draws) read every
    // structure they reach in the hazard model. false leaves those reads out; builds, copies
    // and every other access are still replayed and checked (the consumer bench's peer).
    bool check_consumers = true;
    bool verify_outputs = true;
    // Commands executed, by execution sequence number (ReplayLocation::sequence), inclusive.
    uint64_t first_command = 0;
    uint64_t last_command = std::numeric_limits<uint64_t>::max();
    // Only this submission_index (-1: all).
    int64_t submission = -1;
    std::size_t max_findings =
        1000;  // findings kept (hazards and notes: the same cap); the rest counted
    uint32_t max_findings_per_rule = 64;  // per command, passed to the engine
    // Bytes of captured memory the replay may hold. Every bound buffer is a sparse region
    // that costs only the pages written; a write past the budget is refused (a
    // CLASTRACE-replay-memory-budget finding), and so is a buffer beyond 16 TiB of
    // address space in all.
    uint64_t memory_budget_bytes = 8ull << 30;
    // Per-command rows kept in the report (sizes side by side, commands not replayed);
    // the rest are counted (ReplayReport::rows_over_cap), so memory stays bounded.
    std::size_t max_command_rows = 4096;
    // Record bytes of submitted command buffers kept for resubmission. Beyond it the
    // least recently submitted are dropped; resubmitting one is a
    // CLASTRACE-replay-command-buffer-dropped finding.
    uint64_t max_recorded_bytes = 256ull << 20;
    // Called about every 64 records; may be empty.
    std::function<void(const ReplayProgress&)> progress;
    // Sees every record, submission, command, finding and hazard as the replay meets them
    // (replay_observer.h); may be null. Not owned.
    ReplayObserver* observer = nullptr;
    // How ray checks (RayQueryCheck records) trace the rebuilt structures;
    // `clastrace replay --traversal float32|double` sets it.
    RayCheckTraversal ray_check_traversal = RayCheckTraversal::kCapturingDevice;
    // Threads the replay may use (`clastrace replay --threads N`); 0: the machine's cores as
    // TBB counts them (affinity mask and cgroup quota included). The replay runs in a TBB arena
    // of this size: the ops of a cluster build and the halves of an NV/KHR tree build run in
    // parallel there, and 1 runs everything on the calling thread. The report (results,
    // findings, hazards and their order) is the same for every count (docs/replay.md).
    uint32_t threads = 0;
    // With 2 or more threads: the sync model on a thread of its own, and cluster builds run
    // ahead of their turn on images of their own (docs/replay.md "Threads"). With runs ahead
    // the model's thread is on too, unless CLASTRACE_REPLAY_SYNC_THREAD=0 (session 12: the
    // model's calls were the largest part of the replay thread's own work left); =1 turns it on
    // without them. Runs ahead are on by default from 2 threads (the device's 16-core replay: 1.68x
    // over one thread against 0.96x with every build in its turn, session 11); since session 12
    // a run's state comes from the replay's pool, so their peak memory grows far less with the
    // trace's length (docs/benchmarks.md, s12-runahead). CLASTRACE_REPLAY_RUN_AHEAD=0 in the environment turns
    // them off whatever this says, =1 on. The report is the same either way.
    bool sync_model_thread = false;
    bool run_ahead = true;
    // Runs ahead, counted here when not null. Not owned.
    struct RunAheadCounts {
        uint64_t started = 0;    // runs started ahead
        uint64_t stood = 0;      // taken at the command's turn
        uint64_t run_again = 0;  // checked at the command's turn and run again in place
        // The most runs started and not yet given back at once (each makes an image of its
        // own): the window's capacity (4 x threads, at most 64) and the one being taken. A run
        // gives its image back at its command's turn; a later BLAS run keeps only what it wrote.
        uint64_t most_images = 0;
        // The most CLAS and template runs kept at once after their turn for BLAS runs to start
        // on: those after the BLAS record before the first BLAS that may still start (each
        // holds what it read and wrote), at most the window's capacity.
        uint64_t most_builds_kept = 0;
    };
    RunAheadCounts* run_ahead_counts = nullptr;
};

// The threads replay_trace uses for `options` (options.threads, or the machine's count for 0).
uint32_t replay_threads(const ReplayOptions& options);

// A trace "was made by clastrace's own engine" when its device's driver_name starts with
// "clastrace" (docs/replay.md): its captured outputs must then equal the engine's bytes.
bool is_engine_device(const std::string& driver_name);

// Replays everything `reader` yields from its current position. `trace_name` names the
// file in the report. Never throws on bad input: damage and faults become findings.
ReplayReport replay_trace(traces::TraceReader& reader, const std::string& trace_name,
                          const ReplayOptions& options = {});

}  // namespace clastrace::replay
