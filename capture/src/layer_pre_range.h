// SPDX-License-Identifier: Apache-2.0
// Pre-range state (capture/README.md, "Frame ranges"): with CLASTRACE_FRAME_RANGE starting after
// frame 0, the layer still reads the builds and copies of acceleration structures submitted
// before the range, keeps the last one of each structure that is still alive, and writes them at
// the start of the range as one synthetic submission (the prelude), so replay has the structures
// that the captured frames trace, build over or copy.
#pragma once

#include "clastrace/capture/capture_records.h"
#include "pause_worker.h"

#include <vulkan/vulkan_core.h>

#include <cstdint>
#include <functional>
#include <vector>

namespace clastrace::capture {

struct DeviceState;

// The command buffer handle the prelude's commands are recorded under: not a pointer any
// driver hands out (non-canonical on x86-64 and arm64), so it never names an application's.
constexpr uint64_t kPreRangeCommandBuffer = 0xC1A5'7ACE'0000'0001ull;

// Whether submission `index`, made now and not captured, comes before the frame range and so
// has its acceleration-structure builds and copies read for the prelude.
bool before_frame_range(const DeviceState& device, uint64_t index);

// Whether `pause` is the capture of a command whose outputs the prelude may need: a KHR build
// or copy, or an NV build.
bool produces_pre_range_state(const PausePoint& pause);

// Submission `index` (before the range) ran `pauses` of its command buffers, in execution
// order: each produced structure's older kept command is superseded.
void note_pre_range_submission(DeviceState& device, const SubmissionRecord& submission,
                               const std::vector<const PausePoint*>& pauses);

// What tells when the application saw a submission before the range complete.
struct PreRangeSubmission {
    uint64_t queue = 0, fence = 0;
    std::vector<SemaphoreUse> last_signals;  // its last batch's (signalled after all of it ran)
};

// The application saw submissions complete (a fence, semaphore, queue or device wait returned):
// those before the range that `completes` accepts, and every earlier one on their queues. The
// prelude waits for their captures (write_pre_range_prelude).
void note_pre_range_wait(DeviceState& device,
                         const std::function<bool(const PreRangeSubmission&)>& completes);

// The pause worker's finished record: true when it belongs to a submission before the range
// (kept, or dropped when superseded meanwhile), so the caller hands it to no sink.
bool take_pre_range_capture(DeviceState& device, ClusterBuildCapture& capture);

// The structure was destroyed: its kept build is no longer needed.
void forget_pre_range_structure(DeviceState& device, uint64_t acceleration_structure);

// Memory `memory` was freed: the structures kept in it (KHR ones through their buffers, NV ones
// bound to it, cluster objects at the addresses of buffers bound to it) no longer hold anything,
// so their kept builds go.
void forget_pre_range_memory(DeviceState& device, uint64_t memory);

// An NV structure was bound to `memory` (vkBindAccelerationStructureMemoryNV).
void note_pre_range_nv_memory(DeviceState& device, uint64_t acceleration_structure,
                              uint64_t memory);

// The first captured submission is being planned: true when a prelude is due (state was kept),
// which then takes the submission index before the captured one's.
bool pre_range_prelude_due(DeviceState& device);

// Writes the prelude as submission `index` on `queue` (its family and index as given), then a
// device wait, so replay sees the structures built and visible before anything captured.
void write_pre_range_prelude(DeviceState& device, const SubmissionRecord& captured, uint64_t index);

}  // namespace clastrace::capture
