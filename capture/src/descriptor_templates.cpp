// SPDX-License-Identifier: Apache-2.0
// Descriptor update templates: the layer keeps each template's entries, and turns an update
// (vkUpdateDescriptorSetWithTemplate, vkCmdPushDescriptorSetWithTemplateKHR) back into the
// VkWriteDescriptorSet each entry stands for, so that storage and uniform buffers and acceleration
// structures written this way are followed by the one descriptor-tracking path
// (track_descriptor_write, track_pushed_descriptor_write). Inline uniform blocks and image
// entries only clear what the layer knew of their elements.
#include "command_buffer_log.h"
#include "layer_state.h"

#include <cstring>

namespace clastrace::capture {
namespace {

DeviceState& device_of(VkDevice device) { return *find_device(dispatch_key(device)); }

// One entry's descriptors read from the application's `data`, as a write into `set`. The
// vectors own what the write points to.
struct EntryWrite {
    VkWriteDescriptorSet write{};
    std::vector<VkDescriptorBufferInfo> buffers;
    std::vector<VkAccelerationStructureKHR> khr_structures;
    std::vector<VkAccelerationStructureNV> nv_structures;
    VkWriteDescriptorSetAccelerationStructureKHR khr{};
    VkWriteDescriptorSetAccelerationStructureNV nv{};
};

template <typename T>
std::vector<T> read_entry(const VkDescriptorUpdateTemplateEntry& entry, const void* data) {
    std::vector<T> out(entry.descriptorCount);
    const auto* bytes = static_cast<const uint8_t*>(data) + entry.offset;
    for (uint32_t i = 0; i < entry.descriptorCount; ++i)
        std::memcpy(&out[i], bytes + size_t(i) * entry.stride, sizeof(T));
    return out;
}

// Filled in place: `out.write` points into `out`, so it is never copied after this.
void entry_write(const VkDescriptorUpdateTemplateEntry& entry, VkDescriptorSet set,
                 const void* data, EntryWrite& out) {
    out.write.sType = VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET;
    out.khr.sType = VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET_ACCELERATION_STRUCTURE_KHR;
    out.nv.sType = VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET_ACCELERATION_STRUCTURE_NV;
    out.write.dstSet = set;
    out.write.dstBinding = entry.dstBinding;
    out.write.dstArrayElement = entry.dstArrayElement;
    out.write.descriptorCount = entry.descriptorCount;
    out.write.descriptorType = entry.descriptorType;
    switch (entry.descriptorType) {
    case VK_DESCRIPTOR_TYPE_STORAGE_BUFFER:
    case VK_DESCRIPTOR_TYPE_STORAGE_BUFFER_DYNAMIC:
    case VK_DESCRIPTOR_TYPE_UNIFORM_BUFFER:
    case VK_DESCRIPTOR_TYPE_UNIFORM_BUFFER_DYNAMIC:
        out.buffers = read_entry<VkDescriptorBufferInfo>(entry, data);
        out.write.pBufferInfo = out.buffers.data();
        break;
    case VK_DESCRIPTOR_TYPE_ACCELERATION_STRUCTURE_KHR:
        out.khr_structures = read_entry<VkAccelerationStructureKHR>(entry, data);
        out.khr.accelerationStructureCount = entry.descriptorCount;
        out.khr.pAccelerationStructures = out.khr_structures.data();
        out.write.pNext = &out.khr;
        break;
    case VK_DESCRIPTOR_TYPE_ACCELERATION_STRUCTURE_NV:
        out.nv_structures = read_entry<VkAccelerationStructureNV>(entry, data);
        out.nv.accelerationStructureCount = entry.descriptorCount;
        out.nv.pAccelerationStructures = out.nv_structures.data();
        out.write.pNext = &out.nv;
        break;
    default: break;  // the write clears those elements in the layer's view
    }
}

// The template's entries and bind point, or none.
bool template_of(DeviceState& d, VkDescriptorUpdateTemplate handle,
                 DeviceState::DescriptorTemplate& out) {
    std::lock_guard lock(d.descriptors_mutex);
    auto it = d.descriptor_templates.find(handle_id(handle));
    if (it == d.descriptor_templates.end()) return false;
    out = it->second;
    return true;
}

VkResult create_template(VkDevice device, const VkDescriptorUpdateTemplateCreateInfo* info,
                         const VkAllocationCallbacks* allocator, VkDescriptorUpdateTemplate* out,
                         PFN_vkCreateDescriptorUpdateTemplate next) {
    DeviceState& d = device_of(device);
    const VkResult result = next(device, info, allocator, out);
    if (result != VK_SUCCESS) return result;
    DeviceState::DescriptorTemplate t;
    t.entries.assign(info->pDescriptorUpdateEntries,
                     info->pDescriptorUpdateEntries + info->descriptorUpdateEntryCount);
    t.bind_point = info->pipelineBindPoint;
    std::lock_guard lock(d.descriptors_mutex);
    d.descriptor_templates[handle_id(*out)] = std::move(t);
    return result;
}

VKAPI_ATTR VkResult VKAPI_CALL CreateDescriptorUpdateTemplate(
    VkDevice device, const VkDescriptorUpdateTemplateCreateInfo* info,
    const VkAllocationCallbacks* allocator, VkDescriptorUpdateTemplate* out) {
    return create_template(device, info, allocator, out,
                           device_of(device).next.CreateDescriptorUpdateTemplate);
}
VKAPI_ATTR VkResult VKAPI_CALL CreateDescriptorUpdateTemplateKHR(
    VkDevice device, const VkDescriptorUpdateTemplateCreateInfo* info,
    const VkAllocationCallbacks* allocator, VkDescriptorUpdateTemplate* out) {
    return create_template(device, info, allocator, out,
                           device_of(device).next.CreateDescriptorUpdateTemplateKHR);
}

void destroy_template(VkDevice device, VkDescriptorUpdateTemplate handle,
                      const VkAllocationCallbacks* allocator,
                      PFN_vkDestroyDescriptorUpdateTemplate next) {
    DeviceState& d = device_of(device);
    {
        std::lock_guard lock(d.descriptors_mutex);
        d.descriptor_templates.erase(handle_id(handle));
    }
    next(device, handle, allocator);
}
VKAPI_ATTR void VKAPI_CALL DestroyDescriptorUpdateTemplate(VkDevice device,
                                                           VkDescriptorUpdateTemplate handle,
                                                           const VkAllocationCallbacks* allocator) {
    destroy_template(device, handle, allocator,
                     device_of(device).next.DestroyDescriptorUpdateTemplate);
}
VKAPI_ATTR void VKAPI_CALL DestroyDescriptorUpdateTemplateKHR(
    VkDevice device, VkDescriptorUpdateTemplate handle, const VkAllocationCallbacks* allocator) {
    destroy_template(device, handle, allocator,
                     device_of(device).next.DestroyDescriptorUpdateTemplateKHR);
}

void update_with_template(VkDevice device, VkDescriptorSet set, VkDescriptorUpdateTemplate handle,
                          const void* data, PFN_vkUpdateDescriptorSetWithTemplate next) {
    DeviceState& d = device_of(device);
    next(device, set, handle, data);
    DeviceState::DescriptorTemplate t;
    if (!data || !template_of(d, handle, t)) return;
    for (const VkDescriptorUpdateTemplateEntry& entry : t.entries) {
        EntryWrite w;
        entry_write(entry, set, data, w);
        track_descriptor_write(d, w.write);
    }
}
VKAPI_ATTR void VKAPI_CALL UpdateDescriptorSetWithTemplate(VkDevice device, VkDescriptorSet set,
                                                           VkDescriptorUpdateTemplate handle,
                                                           const void* data) {
    update_with_template(device, set, handle, data,
                         device_of(device).next.UpdateDescriptorSetWithTemplate);
}
VKAPI_ATTR void VKAPI_CALL UpdateDescriptorSetWithTemplateKHR(VkDevice device, VkDescriptorSet set,
                                                              VkDescriptorUpdateTemplate handle,
                                                              const void* data) {
    update_with_template(device, set, handle, data,
                         device_of(device).next.UpdateDescriptorSetWithTemplateKHR);
}

VKAPI_ATTR void VKAPI_CALL CmdPushDescriptorSetWithTemplateKHR(VkCommandBuffer cb,
                                                               VkDescriptorUpdateTemplate handle,
                                                               VkPipelineLayout layout,
                                                               uint32_t set, const void* data) {
    DeviceState& d = *find_device(dispatch_key(cb));
    d.next.CmdPushDescriptorSetWithTemplateKHR(cb, handle, layout, set, data);
    DeviceState::DescriptorTemplate t;
    if (!data || !template_of(d, handle, t)) return;
    for (const VkDescriptorUpdateTemplateEntry& entry : t.entries) {
        EntryWrite w;
        entry_write(entry, VK_NULL_HANDLE, data, w);
        track_pushed_descriptor_write(d, cb, t.bind_point, set, w.write);
    }
}

}  // namespace

PFN_vkVoidFunction descriptor_template_hook(const char* name) {
#define CLASTRACE_TEMPLATE_HOOK(fn) \
    if (std::strcmp(name, "vk" #fn) == 0) return (PFN_vkVoidFunction)fn;
    CLASTRACE_TEMPLATE_HOOK(CreateDescriptorUpdateTemplate)
    CLASTRACE_TEMPLATE_HOOK(CreateDescriptorUpdateTemplateKHR)
    CLASTRACE_TEMPLATE_HOOK(DestroyDescriptorUpdateTemplate)
    CLASTRACE_TEMPLATE_HOOK(DestroyDescriptorUpdateTemplateKHR)
    CLASTRACE_TEMPLATE_HOOK(UpdateDescriptorSetWithTemplate)
    CLASTRACE_TEMPLATE_HOOK(UpdateDescriptorSetWithTemplateKHR)
    CLASTRACE_TEMPLATE_HOOK(CmdPushDescriptorSetWithTemplateKHR)
#undef CLASTRACE_TEMPLATE_HOOK
    return nullptr;
}

}  // namespace clastrace::capture
