// SPDX-License-Identifier: Apache-2.0
#include "clastrace/trace_building/consumer_records.h"

#include <cstring>

namespace clastrace::trace_building {

fbs::AccelerationStructureBinding structure_binding(uint64_t handle, uint64_t address, uint32_t set,
                                                    uint32_t binding, uint32_t array_element) {
    return fbs::AccelerationStructureBinding(set, binding, array_element, 0, handle, address);
}

fbs::CmdTraceRaysT trace_rays(uint64_t command_buffer,
                              std::vector<fbs::AccelerationStructureBinding> structures,
                              uint32_t width, uint32_t height) {
    fbs::CmdTraceRaysT t;
    t.command_buffer = command_buffer;
    t.pipeline = 0x717E;
    t.entry_point = "vkCmdTraceRaysKHR";
    t.width = width;
    t.height = height;
    t.depth = 1;
    t.acceleration_structures = std::move(structures);
    return t;
}

fbs::CmdDispatchT ray_query_dispatch(uint64_t command_buffer,
                                     std::vector<fbs::AccelerationStructureBinding> structures) {
    fbs::CmdDispatchT d;
    d.command_buffer = command_buffer;
    d.pipeline = 0x7C0;
    d.group_count_x = d.group_count_y = d.group_count_z = 1;
    d.ray_query = true;
    d.acceleration_structures = std::move(structures);
    return d;
}

fbs::CmdDrawT ray_query_draw(uint64_t command_buffer, uint64_t stages,
                             std::vector<fbs::AccelerationStructureBinding> structures) {
    fbs::CmdDrawT d;
    d.command_buffer = command_buffer;
    d.pipeline = 0x7D0;
    d.entry_point = "vkCmdDraw";
    d.ray_query_stages = stages;
    d.acceleration_structures = std::move(structures);
    return d;
}

std::vector<uint8_t> packed_instances(const std::vector<uint64_t>& references) {
    std::vector<uint8_t> bytes(references.size() * 64, 0);
    for (size_t i = 0; i < references.size(); ++i) {
        uint8_t* instance = bytes.data() + i * 64;
        const float identity[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
        std::memcpy(instance, identity, sizeof identity);
        const uint32_t index_and_mask = uint32_t(i & 0xFFFFFF) | 0xFFu << 24;
        std::memcpy(instance + 48, &index_and_mask, 4);
        std::memcpy(instance + 56, &references[i], 8);
    }
    return bytes;
}

fbs::QueuePresentT queue_present(uint64_t queue, uint64_t frame) {
    fbs::QueuePresentT p;
    p.queue = queue;
    p.frame = frame;
    p.swapchains = {0x5C0};
    p.image_indices = {uint32_t(frame % 3)};
    return p;
}

}  // namespace clastrace::trace_building
