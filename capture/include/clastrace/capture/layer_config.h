// SPDX-License-Identifier: Apache-2.0
// The capture layer's settings, read once from the environment of the captured process.
#pragma once

#include "clastrace/capture/background_cpus.h"

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

namespace clastrace::capture {

enum class ServeMode {
    kAuto,
    kOff,
    kOn
};  // Auto: serve exactly when the driver lacks the extension
enum class LogLevel { kQuiet, kError, kInfo, kDebug };

struct IndexRange {  // inclusive, 0-based: queue-submission or frame indices
    uint64_t first = 0;
    uint64_t last = UINT64_MAX;
    bool contains(uint64_t index) const { return index >= first && index <= last; }
};
using SubmitRange = IndexRange;

struct LayerConfig {
    bool capture = true;                 // CLASTRACE_CAPTURE
    ServeMode serve = ServeMode::kAuto;  // CLASTRACE_SERVE
    std::string output_path;             // CLASTRACE_OUTPUT (.clt trace)
    // CLASTRACE_OUTPUT_FD: the output already opened and locked by `clastrace capture`, handed
    // down to the application (traces::adopt_output checks it is CLASTRACE_OUTPUT); -1: none.
    int output_fd = -1;
    SubmitRange submit_range;  // CLASTRACE_SUBMIT_RANGE: "N", "A-B", "A-"
    // CLASTRACE_FRAME_RANGE, same syntax: frame N is what is submitted after the N-th
    // vkQueuePresentKHR and up to the (N+1)-th. A submission is captured only when it is in
    // both ranges.
    IndexRange frame_range;
    int zstd_level = 3;               // CLASTRACE_ZSTD_LEVEL: 1..22
    LogLevel log = LogLevel::kError;  // CLASTRACE_LOG: quiet|error|info|debug
    std::string debug_json_path;      // CLASTRACE_DEBUG_JSON: readable dump for tests and debugging
    uint32_t ray_check_rays =
        0;  // CLASTRACE_RAY_CHECK: rays per NV or KHR top-level check, 0 = off
    uint32_t flush_milliseconds =
        1000;  // CLASTRACE_FLUSH_MS: a killed process loses at most this much (0: never)
    bool force_staging =
        false;  // CLASTRACE_FORCE_STAGING: treat all memory as not host visible (tests)
    // CLASTRACE_PRE_RANGE_STATE: a frame range starting after frame 0 carries the structures
    // built before it (layer_pre_range.h); 0 captures the range alone.
    bool pre_range_state = true;
    // CLASTRACE_DEVICE_ADDRESS_WRITES: `cheap` marks dispatches and draws whose pipeline's SPIR-V
    // may write through buffer device addresses (replay: possible hazards); `off` does not.
    bool mark_device_address_writers = true;
    // `exact`: marked dispatches are also paused before and after, and the bytes they changed
    // are written as a DeviceAddressWrites record (exact_address_writes.h); draws stay cheap.
    bool exact_device_address_writes = false;
    bool timestamps = true;  // CLASTRACE_TIMESTAMPS: GPU timestamps around each captured command
    bool stats = false;  // CLASTRACE_STATS: where capture's time went, on stderr at vkDestroyDevice
    // CLASTRACE_HOST_WRITES: watch the mapped inputs of captured commands for host writes
    // between vkQueueSubmit and the wait that orders them (host_write_watch.h).
    bool host_writes = true;
    // `guard` (and `1`): the watch learns which watched pages the host wrote from write faults on
    // pages it made read-only, falling back to hashing where mprotect refuses; `hash`: it hashes
    // every watched range at the submission and again at the wait (page_guard.h).
    bool host_write_guard = true;
    // CLASTRACE_GUARD_REST: a guarded page nobody wrote stays read-only after its wait, so the
    // next submission watches it without an mprotect (the default). 0 makes every page writable
    // at its wait: for an application whose system calls write into mapped memory a build read
    // (`read(2)` into a mapped buffer fails with EFAULT on a read-only page).
    bool guard_rest = true;
    // CLASTRACE_DELTA_CONTENTS: store a range's new contents XOR its previous contents
    // (TraceWriterOptions::delta_contents); 0 stores every content whole (format 1.6 readers).
    bool delta_contents = true;
    // CLASTRACE_SHARED_WAIT_MS: how long a submission waits for another queue to finish with the
    // pause events of a simultaneous-use command buffer (layer_submit.cpp) before it goes ahead.
    uint32_t shared_wait_milliseconds = 10000;
    BackgroundCpus
        background_cpus;  // CLASTRACE_BACKGROUND_CPUS: spare|app|a CPU list (background_cpus.h)
    std::vector<std::string> errors;  // one line per rejected variable; the default is kept
};

// Parses the variables through `getenv` (injectable for tests). Never throws.
LayerConfig parse_layer_config(const std::function<const char*(const char*)>& getenv);

// The process-wide configuration: parsed on first use, its errors printed to stderr once.
const LayerConfig& layer_config();

}  // namespace clastrace::capture
