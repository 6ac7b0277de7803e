// SPDX-License-Identifier: Apache-2.0
// Where the layer sends what it captured: one call per record kind. Calls may come from the
// application's threads and from the layer's pause worker; implementations serialize them.
#pragma once

#include "clastrace/capture/capture_records.h"

#include <memory>
#include <string>
#include <vector>

namespace clastrace::capture {

class CaptureSink {
public:
    virtual ~CaptureSink() = default;
    virtual void device_created(const DeviceRecord&) = 0;
    virtual void device_destroyed(uint64_t device) = 0;
    virtual void memory_allocated(const MemoryRecord&) = 0;
    virtual void memory_freed(uint64_t memory) = 0;
    virtual void buffer_created(const BufferRecord&) = 0;
    virtual void buffer_bound(const BufferBindingRecord&) = 0;
    virtual void buffer_address_queried(const BufferAddressRecord&) = 0;
    virtual void buffer_destroyed(uint64_t buffer) = 0;
    virtual void build_sizes_queried(const BuildSizesQuery&) = 0;
    virtual void command_buffer_recorded(const RecordedCommandBuffer&) = 0;
    virtual void command_buffer_reset(uint64_t command_buffer) = 0;
    virtual void queue_submitted(const SubmissionRecord&) = 0;
    virtual void cluster_build_captured(
        ClusterBuildCapture) = 0;  // by value: the worker moves it in
    virtual void host_synchronized(const HostSyncRecord&) = 0;
    // A host write to mapped memory a submitted command reads (no-op unless a sink records it).
    virtual void host_write_observed(const HostWriteRecord&) {}
    // False once the sink stopped writing (its one message printed): the layer then saves the
    // work of capturing, and the application runs on as with capture off.
    virtual bool active() const { return true; }
    // Acceleration-structure objects and the ray check (no-ops unless a sink records them).
    virtual void acceleration_structure_created(const AccelerationStructureRecord&) {}
    virtual void acceleration_structure_bound(const AccelerationStructureBindingRecord&) {}
    virtual void acceleration_structure_address_queried(const AccelerationStructureAddressRecord&) {
    }
    virtual void acceleration_structure_memory_requirements(
        const AccelerationStructureMemoryRequirementsRecord&) {}
    virtual void acceleration_structure_destroyed(uint64_t) {}
    virtual void ray_query_checked(const RayCheckRecord&) {}
    // vkQueuePresentKHR, recorded whatever the frame range selects (frame boundaries).
    virtual void queue_presented(const PresentRecord&) {}
    // vkAcquireNextImage[2]KHR, recorded like presents (in call order, whatever the range).
    virtual void image_acquired(const AcquireRecord&) {}
    // vkQueueBindSparse, in queue order with the submissions (read during the call).
    virtual void sparse_bound(const SparseBindRecord&) {}
    // vkGetQueryPoolResults of acceleration-structure property queries, and
    // vkGetAccelerationStructureBuildSizesKHR, in call order (no-ops unless a sink records them).
    virtual void query_pool_results_read(const QueryPoolResultsRecord&) {}
    virtual void khr_build_sizes_queried(const KhrBuildSizesQuery&) {}
    // VkFrameBoundaryEXT on a submission or present, recorded like presents (whatever the range).
    virtual void frame_boundary_marked(const FrameBoundaryRecord&) {}
    // The prelude of a frame range follows (its submission, then a device wait).
    virtual void pre_range_state_written(const PreRangeStateRecord&) {}
    // Frees the captured bytes of records already written, on the calling thread. The pause
    // worker calls it when idle: the bytes were allocated on its thread, and freeing them there
    // spares the sink's thread the allocator's cross-thread path (and the worker's allocations
    // inside the next pause the contention on its arena's lock).
    virtual void release_written() {}
    // Makes everything received so far durable (the application may exit without cleanup).
    virtual void flush() = 0;
    // Lines for the CLASTRACE_STATS report: what the sink wrote and where its time went.
    virtual std::vector<std::string> cost_lines() { return {}; }
};

// A human-readable dump of every record (JSON, rewritten on each flush): the test suites read
// it, and it helps debugging a capture before a trace reader exists. False + `error` when the
// path cannot be written.
std::unique_ptr<CaptureSink> make_json_capture_sink(const std::string& path, std::string& error);

// The .clt trace the replay reads (CLASTRACE_OUTPUT). Null + `error` when the path cannot be
// written, or while this build has no trace writer.
// Every `flushMilliseconds` (0: never) the records so far are written out as a finished chunk,
// so a process that is killed loses at most that much of its capture.
// Its two threads (the sink's and the compressor's) run on `placement.cpus` when not empty
// (background_cpus.h); `application_cpus` and `application_siblings` are only reported.
struct BackgroundPlacement {
    std::vector<unsigned> cpus;
    std::vector<unsigned> application_cpus;
    std::vector<unsigned> application_siblings;  // SMT siblings of application_cpus
};
// The output follows traces/output_file.h's rule and is written in place: it is opened (or,
// with `inheritedFd` >= 0, taken over from `clastrace capture`) and locked here, and emptied
// only when the first device starts the trace. Another process holding the lock (another
// capture of the same path) makes this fail with `error` saying so.
std::unique_ptr<CaptureSink> make_trace_capture_sink(const std::string& path, int zstd_level,
                                                     std::string& error,
                                                     uint32_t flush_milliseconds = 1000,
                                                     BackgroundPlacement placement = {},
                                                     int inherited_fd = -1);

}  // namespace clastrace::capture
