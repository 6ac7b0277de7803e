// SPDX-License-Identifier: Apache-2.0
// Acceleration structures reached through descriptor buffers (VK_EXT_descriptor_buffer; source
// 2 of a consumer's structures). The application asks vkGetDescriptorEXT for an acceleration
// structure's descriptor and copies the bytes into a buffer; the layer remembers the bytes of
// each answer with the address asked for. At each reading of a consumer's structures (recording,
// and again at submission) it reads, for each set taken from a descriptor buffer, the bytes at
// each acceleration-structure binding of the set's layout and looks them up among the answers.
#include "command_buffer_log.h"
#include "layer_state.h"

#include <atomic>
#include <cstring>

namespace clastrace::capture {
namespace {

using Source = ReachableAccelerationStructure::Source;

DeviceState& device_of(VkDevice device) { return *find_device(dispatch_key(device)); }
DeviceState& device_of(VkCommandBuffer cb) { return *find_device(dispatch_key(cb)); }

bool is_acceleration_structure(VkDescriptorType type) {
    return type == VK_DESCRIPTOR_TYPE_ACCELERATION_STRUCTURE_KHR ||
           type == VK_DESCRIPTOR_TYPE_ACCELERATION_STRUCTURE_NV;
}

VKAPI_ATTR VkResult VKAPI_CALL
CreateDescriptorSetLayout(VkDevice device, const VkDescriptorSetLayoutCreateInfo* info,
                          const VkAllocationCallbacks* allocator, VkDescriptorSetLayout* out) {
    DeviceState& d = device_of(device);
    const VkResult result = d.next.CreateDescriptorSetLayout(device, info, allocator, out);
    if (result != VK_SUCCESS) return result;
    const bool in_buffers =
        (info->flags & VK_DESCRIPTOR_SET_LAYOUT_CREATE_DESCRIPTOR_BUFFER_BIT_EXT) != 0 &&
        d.next.GetDescriptorSetLayoutBindingOffsetEXT;
    std::vector<AccelerationStructureBindingLayout> bindings;
    for (uint32_t i = 0; in_buffers && i < info->bindingCount; ++i) {
        const VkDescriptorSetLayoutBinding& b = info->pBindings[i];
        if (!is_acceleration_structure(b.descriptorType) || b.descriptorCount == 0) continue;
        AccelerationStructureBindingLayout layout{b.binding, b.descriptorCount, 0};
        // A pure query of the driver: the same answer the application gets.
        d.next.GetDescriptorSetLayoutBindingOffsetEXT(device, *out, b.binding, &layout.offset);
        bindings.push_back(layout);
    }
    std::lock_guard lock(d.descriptor_buffers.mutex);
    if (bindings.empty())  // a reused handle must not keep an older layout's bindings
        d.descriptor_buffers.set_layouts.erase(handle_id(*out));
    else
        d.descriptor_buffers.set_layouts[handle_id(*out)] = std::move(bindings);
    return result;
}

VKAPI_ATTR VkResult VKAPI_CALL CreatePipelineLayout(VkDevice device,
                                                    const VkPipelineLayoutCreateInfo* info,
                                                    const VkAllocationCallbacks* allocator,
                                                    VkPipelineLayout* out) {
    DeviceState& d = device_of(device);
    const VkResult result = d.next.CreatePipelineLayout(device, info, allocator, out);
    if (result != VK_SUCCESS) return result;
    std::vector<uint64_t> set_layouts;
    for (uint32_t i = 0; i < info->setLayoutCount; ++i)
        set_layouts.push_back(handle_id(info->pSetLayouts[i]));
    std::lock_guard lock(d.descriptor_buffers.mutex);
    d.descriptor_buffers.pipeline_layouts[handle_id(*out)] = std::move(set_layouts);
    return result;
}

VKAPI_ATTR void VKAPI_CALL GetDescriptorEXT(VkDevice device, const VkDescriptorGetInfoEXT* info,
                                            size_t size, void* descriptor) {
    DeviceState& d = device_of(device);
    d.next.GetDescriptorEXT(device, info, size, descriptor);
    if (!is_acceleration_structure(info->type) || info->data.accelerationStructure == 0 ||
        size == 0)
        return;
    const auto* bytes = static_cast<const uint8_t*>(descriptor);
    std::lock_guard lock(d.descriptor_buffers.mutex);
    d.descriptor_buffers.structure_descriptors[std::vector<uint8_t>(bytes, bytes + size)] =
        info->data.accelerationStructure;
    d.descriptor_buffers.descriptor_size = size;
}

VKAPI_ATTR void VKAPI_CALL CmdBindDescriptorBuffersEXT(
    VkCommandBuffer cb, uint32_t count, const VkDescriptorBufferBindingInfoEXT* infos) {
    DeviceState& d = device_of(cb);
    d.next.CmdBindDescriptorBuffersEXT(cb, count, infos);
    auto log = command_buffer_log_of(d, cb);
    log->descriptor_buffers.clear();  // binding points past `count` are unbound
    for (uint32_t i = 0; i < count; ++i) log->descriptor_buffers.push_back(infos[i].address);
}

VKAPI_ATTR void VKAPI_CALL CmdSetDescriptorBufferOffsetsEXT(
    VkCommandBuffer cb, VkPipelineBindPoint bind_point, VkPipelineLayout layout, uint32_t first_set,
    uint32_t set_count, const uint32_t* buffer_indices, const VkDeviceSize* offsets) {
    DeviceState& d = device_of(cb);
    d.next.CmdSetDescriptorBufferOffsetsEXT(cb, bind_point, layout, first_set, set_count,
                                            buffer_indices, offsets);
    const int index = bind_point_index(bind_point);
    if (index < 0) return;
    std::vector<uint64_t> set_layouts;
    {
        std::lock_guard lock(d.descriptor_buffers.mutex);
        auto known = d.descriptor_buffers.pipeline_layouts.find(handle_id(layout));
        if (known != d.descriptor_buffers.pipeline_layouts.end()) set_layouts = known->second;
    }
    auto log = command_buffer_log_of(d, cb);
    log->forget_pushed_sets(index, first_set, set_count);
    CommandBufferLog::BoundSets* sets = log->sets_at(bind_point);
    for (uint32_t i = 0; i < set_count; ++i) {
        const uint32_t set = first_set + i;
        if (sets) sets->erase(set);  // a set from a buffer replaces a bound descriptor set
        if (set >= set_layouts.size()) continue;
        log->descriptor_buffer_offsets[index][set] = {set_layouts[set], buffer_indices[i],
                                                      offsets[i]};
    }
}

// The handle of the structure at `address`, 0 when the layer does not know it.
uint64_t structure_at(DeviceState& d, VkDeviceAddress address) {
    std::lock_guard lock(d.acceleration_structure_addresses_mutex);
    auto it = d.acceleration_structures_by_address.find(address);
    return it == d.acceleration_structures_by_address.end() ? 0 : it->second;
}

void say_not_host_visible(const std::string& why) {
    static std::atomic<bool> said{false};
    if (!said.exchange(true))
        log_message(LogLevel::kInfo,
                    "a descriptor buffer's acceleration-structure descriptors are not followed: "
                    "%s",
                    why.c_str());
}

}  // namespace

DescriptorBufferSets descriptor_buffer_sets_at(const CommandBufferLog& log, int index) {
    DescriptorBufferSets out;
    if (index < 0) return out;
    for (const auto& [set, where] : log.descriptor_buffer_offsets[index]) {
        if (where.buffer_index >= log.descriptor_buffers.size()) continue;
        out[set] = {where.set_layout, log.descriptor_buffers[where.buffer_index] + where.offset};
    }
    return out;
}

void add_descriptor_buffer_structures(DeviceState& d, const DescriptorBufferSets& sets,
                                      std::vector<ReachableAccelerationStructure>& out) {
    if (sets.empty()) return;
    DescriptorBufferRegistry& registry = d.descriptor_buffers;
    std::vector<uint8_t> bytes;
    std::string why;
    for (const auto& [set, where] : sets) {
        std::vector<AccelerationStructureBindingLayout> bindings;
        size_t size = 0;
        {
            std::lock_guard lock(registry.mutex);
            auto known = registry.set_layouts.find(where.set_layout);
            if (known == registry.set_layouts.end()) continue;
            bindings = known->second;
            size = registry.descriptor_size;
        }
        if (size == 0) return;  // no acceleration-structure descriptor asked for yet
        for (const AccelerationStructureBindingLayout& b : bindings) {
            for (uint32_t element = 0; element < b.count; ++element) {
                const VkDeviceAddress at = where.address + b.offset + VkDeviceSize(element) * size;
                if (!d.memory_map.read(at, size, bytes, why)) {
                    say_not_host_visible(why);
                    break;
                }
                VkDeviceAddress address = 0;
                {
                    std::lock_guard lock(registry.mutex);
                    auto found = registry.structure_descriptors.find(bytes);
                    if (found == registry.structure_descriptors.end()) continue;
                    address = found->second;
                }
                ReachableAccelerationStructure r;
                r.set = set;
                r.binding = b.binding;
                r.array_element = element;
                r.source = Source::kDescriptorBuffer;
                r.address = address;
                r.acceleration_structure = structure_at(d, address);
                out.push_back(r);
            }
        }
    }
}

PFN_vkVoidFunction descriptor_buffer_hook(const char* name) {
#define CLASTRACE_DESCRIPTOR_BUFFER_HOOK(fn) \
    if (std::strcmp(name, "vk" #fn) == 0) return (PFN_vkVoidFunction)fn;
    CLASTRACE_DESCRIPTOR_BUFFER_HOOK(CreateDescriptorSetLayout)
    CLASTRACE_DESCRIPTOR_BUFFER_HOOK(CreatePipelineLayout)
    CLASTRACE_DESCRIPTOR_BUFFER_HOOK(GetDescriptorEXT)
    CLASTRACE_DESCRIPTOR_BUFFER_HOOK(CmdBindDescriptorBuffersEXT)
    CLASTRACE_DESCRIPTOR_BUFFER_HOOK(CmdSetDescriptorBufferOffsetsEXT)
#undef CLASTRACE_DESCRIPTOR_BUFFER_HOOK
    return nullptr;
}

}  // namespace clastrace::capture
