// SPDX-License-Identifier: Apache-2.0
// What the layer knows of VK_EXT_descriptor_buffer, per device, to name the acceleration
// structures a consumer reaches through descriptor buffers (consumer_descriptor_buffers.cpp).
#pragma once

#include <vulkan/vulkan_core.h>

#include <cstdint>
#include <map>
#include <mutex>
#include <unordered_map>
#include <vector>

namespace clastrace::capture {

// An acceleration-structure binding of a descriptor-buffer set layout: its descriptors start
// `offset` bytes into the set's range (vkGetDescriptorSetLayoutBindingOffsetEXT), `count` of
// them, one descriptor size apart.
struct AccelerationStructureBindingLayout {
    uint32_t binding = 0, count = 0;
    VkDeviceSize offset = 0;
};

struct DescriptorBufferRegistry {
    std::mutex mutex;
    // The bytes each vkGetDescriptorEXT answered for an acceleration structure -> its address
    // (KHR device address or NV handle), and the size of such a descriptor.
    std::map<std::vector<uint8_t>, VkDeviceAddress> structure_descriptors;
    size_t descriptor_size = 0;
    // Set layouts created with DESCRIPTOR_BUFFER_BIT -> their acceleration-structure bindings.
    std::unordered_map<uint64_t, std::vector<AccelerationStructureBindingLayout>> set_layouts;
    // Pipeline layouts -> their set layouts, by set number.
    std::unordered_map<uint64_t, std::vector<uint64_t>> pipeline_layouts;
};

}  // namespace clastrace::capture
