// SPDX-License-Identifier: Apache-2.0
// VK_EXT_frame_boundary: how a headless program (no vkQueuePresentKHR) says where its frames end.
// A VkFrameBoundaryEXT chained to a submission or a present is recorded as FrameBoundary, and one
// with VK_FRAME_BOUNDARY_FRAME_END_BIT_EXT ends a frame for CLASTRACE_FRAME_RANGE. Where the
// driver lacks the extension the layer provides it (layer_serving.cpp lists it, the features
// struct reads frameBoundary = VK_TRUE) and unlinks the struct from every call it passes down.
#include "layer_state.h"

#include <algorithm>
#include <atomic>

namespace clastrace::capture {
namespace {

std::atomic<uint64_t> presentCalls{0};
std::atomic<uint64_t> frameEnds{0};

}  // namespace

// The two counts are kept apart and the frame is the larger: a program that both marks and
// presents each frame (the mark on the frame's last submission, then the present) counts the
// frame once, at the mark; one that only presents or only marks counts each call.
uint64_t current_frame() { return std::max(presentCalls.load(), frameEnds.load()); }

uint64_t count_present() {
    const uint64_t before = current_frame();
    presentCalls.fetch_add(1);
    // Marks ahead of presents: the frame ended at its mark, and this present is that frame's.
    return current_frame() > before ? before : before - 1;
}

const VkFrameBoundaryEXT* find_frame_boundary(const void* chain) {
    for (auto* s = (const VkBaseInStructure*)chain; s; s = s->pNext)
        if (s->sType == VK_STRUCTURE_TYPE_FRAME_BOUNDARY_EXT) return (const VkFrameBoundaryEXT*)s;
    return nullptr;
}

void frame_boundary_marked(DeviceState& d, VkQueue queue, const VkFrameBoundaryEXT& boundary,
                           FrameBoundaryCarrier carrier, uint64_t submission, uint32_t batch,
                           uint64_t frame) {
    if (boundary.flags & VK_FRAME_BOUNDARY_FRAME_END_BIT_EXT) {
        // A present carrying the mark was counted as a present already: one frame, not two.
        uint64_t ends = frameEnds.load();
        uint64_t raised;
        do {
            raised = carrier == FrameBoundaryCarrier::kPresent ? std::max(ends, presentCalls.load())
                                                               : std::max(ends, frame) + 1;
        } while (!frameEnds.compare_exchange_weak(ends, raised));
    }
    if (!d.capturing_now()) return;
    FrameBoundaryRecord record;
    record.queue = handle_id(queue);
    record.carrier = carrier;
    record.submission = submission;
    record.batch = batch;
    record.flags = boundary.flags;
    record.frame_id = boundary.frameID;
    record.frame = frame;
    for (uint32_t i = 0; i < boundary.imageCount && boundary.pImages; ++i)
        record.images.push_back(handle_id(boundary.pImages[i]));
    for (uint32_t i = 0; i < boundary.bufferCount && boundary.pBuffers; ++i)
        record.buffers.push_back(handle_id(boundary.pBuffers[i]));
    record.tag_name = boundary.tagName;
    if (boundary.pTag && boundary.tagSize)
        record.tag.assign((const uint8_t*)boundary.pTag,
                          (const uint8_t*)boundary.pTag + boundary.tagSize);
    d.sink->frame_boundary_marked(record);
}

}  // namespace clastrace::capture
