// What the layer keeps per application command buffer between vkBeginCommandBuffer and its
// reset: the recorded commands, and the pause points (with the layer's events) to expect when
// it is submitted.
#pragma once

#include "pause_worker.h"

#include <vector>

namespace clastrace::capture {

struct CommandBufferLog {
  RecordedCommandBuffer recorded;
  std::vector<PausePoint> pauses;  // in execution order, secondaries' included
  std::vector<VkEvent> events;     // created by the layer for this recording
};

// Destroys the layer's events of `log` and clears it for a new recording.
void clearCommandBufferLog(DeviceState& device, CommandBufferLog& log);

}  // namespace clastrace::capture
