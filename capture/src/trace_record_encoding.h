// SPDX-License-Identifier: Apache-2.0
// What the capture layer recorded, as trace records: pure functions, no locks, no writer. The
// trace sink (trace_capture_sink.cpp) decides when each record goes out and adds the memory
// snapshots, which need the writer's content store. Vulkan structs that replay decodes again are
// converted by traces/ (cluster_conversions.h, nv_conversions.h), in one place for both sides.
#pragma once

#include "clastrace/capture/capture_records.h"
#include "clastrace/capture/capture_sink.h"

#include <clastrace/traces/trace_generated.h>

#include <cstdint>
#include <memory>
#include <utility>
#include <vector>

namespace clastrace::capture {

template <class T>
fbs::RecordT record_of(T body) {
    fbs::RecordT r;
    r.body.Set(std::move(body));
    return r;
}

// The trace header of the first device; `startTimeUnixNs` is when the capture began.
fbs::TraceHeaderT trace_header_of(const DeviceRecord& d, uint64_t start_time_unix_ns);

fbs::RecordT host_sync_record_of(const HostSyncRecord& h);

std::unique_ptr<fbs::AccelerationStructureInfoNVT> nv_info_of(
    uint32_t type, uint32_t flags, uint32_t instances, const std::vector<VkGeometryNV>& geometries);

// A command of a recorded command buffer without its snapshots (the sink adds them), or a
// record with no body for the commands the sink writes itself (timestamps, vkCmdExecuteCommands).
fbs::RecordT command_record_of(uint64_t command_buffer, const RecordedCommand& command);

// A KHR build info (its direct ranges, indirect fields and unrecorded pNext sTypes).
std::unique_ptr<fbs::AccelerationStructureBuildInfoKHRT> khr_build_info_of(
    const KhrBuildInfo& info);
// An indirect build's ranges as the capture read them at execution, into its record's infos.
void set_indirect_ranges(
    const std::vector<std::vector<VkAccelerationStructureBuildRangeInfoKHR>>& ranges,
    fbs::CmdBuildAccelerationStructuresKHRT& record);
fbs::QueryPoolResultsT query_pool_results_of(const QueryPoolResultsRecord& q);
fbs::GetAccelerationStructureBuildSizesKHRT khr_build_sizes_of(const KhrBuildSizesQuery& q);

// The QueueSubmit of a submission, numbered `submissionIndex` in the trace.
fbs::QueueSubmitT queue_submit_of(const SubmissionRecord& s, uint64_t submission_index);

// A frame range's pre-range state; `prelude_submission`: its prelude's number in the trace.
fbs::PreRangeStateT pre_range_state_of(const PreRangeStateRecord& m, uint64_t prelude_submission);

// `afterSubmission`: the trace's number of the submission the rays saw (~0: unknown).
fbs::RayQueryCheckT ray_query_check_of(const RayCheckRecord& c, uint64_t after_submission);

// What the build's capture found wrong: the engine's findings when it served the build
// (errors), and ranges the capture could not read.
void collect_findings(uint64_t command_buffer, size_t index, const ClusterBuildCapture& captured,
                      std::vector<fbs::CaptureFindingT>& out);
// A captured command emitted without its pause: its memory is missing from the trace.
fbs::CaptureFindingT uncaptured_command_finding(uint64_t command_buffer, size_t index);
// A note the layer made about a whole command buffer of a submission.
fbs::CaptureFindingT submission_note_finding(const SubmissionRecord::Note& note);

}  // namespace clastrace::capture
