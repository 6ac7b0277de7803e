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
fbs::RecordT recordOf(T body) {
  fbs::RecordT r;
  r.body.Set(std::move(body));
  return r;
}

// The trace header of the first device; `startTimeUnixNs` is when the capture began.
fbs::TraceHeaderT traceHeaderOf(const DeviceRecord& d, uint64_t startTimeUnixNs);

fbs::RecordT hostSyncRecordOf(const HostSyncRecord& h);

std::unique_ptr<fbs::AccelerationStructureInfoNVT> nvInfoOf(uint32_t type, uint32_t flags, uint32_t instances,
                                                            const std::vector<VkGeometryNV>& geometries);

// A command of a recorded command buffer without its snapshots (the sink adds them), or a
// record with no body for the commands the sink writes itself (timestamps, vkCmdExecuteCommands).
fbs::RecordT commandRecordOf(uint64_t commandBuffer, const RecordedCommand& command);

// The QueueSubmit of a submission, numbered `submissionIndex` in the trace.
fbs::QueueSubmitT queueSubmitOf(const SubmissionRecord& s, uint64_t submissionIndex);

// `afterSubmission`: the trace's number of the submission the rays saw (~0: unknown).
fbs::RayQueryCheckT rayQueryCheckOf(const RayCheckRecord& c, uint64_t afterSubmission);

// What the build's capture found wrong: the engine's findings when it served the build
// (errors), and ranges the capture could not read.
void collectFindings(uint64_t commandBuffer, size_t index, const ClusterBuildCapture& captured,
                     std::vector<fbs::CaptureFindingT>& out);
// A captured command emitted without its pause: its memory is missing from the trace.
fbs::CaptureFindingT uncapturedCommandFinding(uint64_t commandBuffer, size_t index);
// A note the layer made about a whole command buffer of a submission.
fbs::CaptureFindingT submissionNoteFinding(const SubmissionRecord::Note& note);

}  // namespace clastrace::capture
