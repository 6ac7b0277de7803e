// SPDX-License-Identifier: Apache-2.0
// NV and KHR acceleration-structure objects (creation, memory, handles and addresses, for the
// replay to rebuild them and translate instance records), the queues' families, and the ray
// check that traces rays against a top level after the submission that built it.
#include "command_buffer_log.h"
#include "layer_pre_range.h"
#include "layer_state.h"

#include "clastrace/capture/khr_ray_tracer.h"

#include <chrono>
#include <cinttypes>
#include <cstring>
#include <map>

namespace clastrace::capture {
namespace {

DeviceState& device_of(VkDevice device) { return *find_device(dispatch_key(device)); }

// ---- NV objects ----------------------------------------------------------------------------

VKAPI_ATTR VkResult VKAPI_CALL CreateAccelerationStructureNV(
    VkDevice device, const VkAccelerationStructureCreateInfoNV* p_create_info,
    const VkAllocationCallbacks* p_allocator, VkAccelerationStructureNV* p_acceleration_structure) {
    DeviceState& d = device_of(device);
    VkResult result = d.next.CreateAccelerationStructureNV(device, p_create_info, p_allocator,
                                                           p_acceleration_structure);
    if (result != VK_SUCCESS || !d.sink) return result;
    AccelerationStructureRecord r;
    r.acceleration_structure = handle_id(*p_acceleration_structure);
    r.type = uint32_t(p_create_info->info.type);
    r.compacted_size = p_create_info->compactedSize;
    r.info_type = uint32_t(p_create_info->info.type);
    r.info_flags = p_create_info->info.flags;
    r.instance_count = p_create_info->info.instanceCount;
    for (uint32_t i = 0; i < p_create_info->info.geometryCount; ++i) {
        VkGeometryNV g = p_create_info->info.pGeometries[i];
        g.pNext = nullptr;
        g.geometry.triangles.pNext = nullptr;
        g.geometry.aabbs.pNext = nullptr;
        r.geometries.push_back(g);
    }
    d.sink->acceleration_structure_created(r);
    return result;
}

VKAPI_ATTR void VKAPI_CALL DestroyAccelerationStructureNV(
    VkDevice device, VkAccelerationStructureNV as, const VkAllocationCallbacks* p_allocator) {
    DeviceState& d = device_of(device);
    if (as) {
        d.nv_scene.forget(handle_id(as));
        forget_acceleration_structure_address(d, handle_id(as));
        forget_pre_range_structure(d, handle_id(as));
        if (d.sink) d.sink->acceleration_structure_destroyed(handle_id(as));
    }
    d.next.DestroyAccelerationStructureNV(device, as, p_allocator);
}

VKAPI_ATTR VkResult VKAPI_CALL BindAccelerationStructureMemoryNV(
    VkDevice device, uint32_t count, const VkBindAccelerationStructureMemoryInfoNV* infos) {
    DeviceState& d = device_of(device);
    VkResult result = d.next.BindAccelerationStructureMemoryNV(device, count, infos);
    if (result == VK_SUCCESS)
        for (uint32_t i = 0; i < count; ++i)
            note_pre_range_nv_memory(d, handle_id(infos[i].accelerationStructure),
                                     handle_id(infos[i].memory));
    if (result == VK_SUCCESS && d.sink)
        for (uint32_t i = 0; i < count; ++i)
            d.sink->acceleration_structure_bound({handle_id(infos[i].accelerationStructure),
                                                  handle_id(infos[i].memory),
                                                  infos[i].memoryOffset});
    return result;
}

VKAPI_ATTR VkResult VKAPI_CALL GetAccelerationStructureHandleNV(VkDevice device,
                                                                VkAccelerationStructureNV as,
                                                                size_t data_size, void* p_data) {
    DeviceState& d = device_of(device);
    VkResult result = d.next.GetAccelerationStructureHandleNV(device, as, data_size, p_data);
    if (result != VK_SUCCESS || data_size < sizeof(uint64_t)) return result;
    uint64_t handle;
    std::memcpy(&handle, p_data, sizeof handle);
    d.nv_scene.set_handle(handle_id(as), handle);
    remember_acceleration_structure_address(d, handle_id(as), handle);
    if (d.sink) d.sink->acceleration_structure_address_queried({handle_id(as), handle});
    return result;
}

VKAPI_ATTR void VKAPI_CALL GetAccelerationStructureMemoryRequirementsNV(
    VkDevice device, const VkAccelerationStructureMemoryRequirementsInfoNV* p_info,
    VkMemoryRequirements2KHR* p_out) {
    DeviceState& d = device_of(device);
    d.next.GetAccelerationStructureMemoryRequirementsNV(device, p_info, p_out);
    if (!d.sink) return;
    const VkMemoryRequirements& m = p_out->memoryRequirements;
    d.sink->acceleration_structure_memory_requirements({handle_id(p_info->accelerationStructure),
                                                        uint32_t(p_info->type), m.size, m.alignment,
                                                        m.memoryTypeBits});
}

// ---- KHR objects ---------------------------------------------------------------------------

VKAPI_ATTR VkResult VKAPI_CALL CreateAccelerationStructureKHR(
    VkDevice device, const VkAccelerationStructureCreateInfoKHR* p_create_info,
    const VkAllocationCallbacks* p_allocator,
    VkAccelerationStructureKHR* p_acceleration_structure) {
    DeviceState& d = device_of(device);
    VkResult result = d.next.CreateAccelerationStructureKHR(device, p_create_info, p_allocator,
                                                            p_acceleration_structure);
    if (result == VK_SUCCESS)
        remember_khr_structure(d, {handle_id(*p_acceleration_structure),
                                   handle_id(p_create_info->buffer), p_create_info->offset,
                                   p_create_info->size});
    if (result != VK_SUCCESS || !d.sink) return result;
    AccelerationStructureRecord r;
    r.acceleration_structure = handle_id(*p_acceleration_structure);
    r.khr = true;
    r.type = uint32_t(p_create_info->type);
    r.buffer = handle_id(p_create_info->buffer);
    r.offset = p_create_info->offset;
    r.size = p_create_info->size;
    r.create_flags = p_create_info->createFlags;
    d.sink->acceleration_structure_created(r);
    return result;
}

VKAPI_ATTR void VKAPI_CALL DestroyAccelerationStructureKHR(
    VkDevice device, VkAccelerationStructureKHR as, const VkAllocationCallbacks* p_allocator) {
    DeviceState& d = device_of(device);
    if (as) forget_khr_structure(d, handle_id(as));
    if (as) forget_pre_range_structure(d, handle_id(as));
    if (as) d.nv_scene.forget(handle_id(as));
    if (as && d.sink) d.sink->acceleration_structure_destroyed(handle_id(as));
    if (as) forget_acceleration_structure_address(d, handle_id(as));
    d.next.DestroyAccelerationStructureKHR(device, as, p_allocator);
}

VKAPI_ATTR VkDeviceAddress VKAPI_CALL GetAccelerationStructureDeviceAddressKHR(
    VkDevice device, const VkAccelerationStructureDeviceAddressInfoKHR* p_info) {
    DeviceState& d = device_of(device);
    VkDeviceAddress address = d.next.GetAccelerationStructureDeviceAddressKHR(device, p_info);
    remember_acceleration_structure_address(d, handle_id(p_info->accelerationStructure), address);
    // KHR instances name their bottom level by this address (the ray check's scene model).
    if (address) d.nv_scene.set_handle(handle_id(p_info->accelerationStructure), address);
    if (d.sink)
        d.sink->acceleration_structure_address_queried(
            {handle_id(p_info->accelerationStructure), address});
    return address;
}

// ---- Queues ------------------------------------------------------------------------------

VKAPI_ATTR void VKAPI_CALL GetDeviceQueue(VkDevice device, uint32_t family, uint32_t index,
                                          VkQueue* p_queue) {
    DeviceState& d = device_of(device);
    d.next.GetDeviceQueue(device, family, index, p_queue);
    std::lock_guard lock(d.queues_mutex);
    if (*p_queue) {
        d.queue_families[*p_queue] = family;
        d.queue_indices[*p_queue] = index;
    }
}

VKAPI_ATTR void VKAPI_CALL GetDeviceQueue2(VkDevice device, const VkDeviceQueueInfo2* p_info,
                                           VkQueue* p_queue) {
    DeviceState& d = device_of(device);
    d.next.GetDeviceQueue2(device, p_info, p_queue);
    std::lock_guard lock(d.queues_mutex);
    if (*p_queue) {
        d.queue_families[*p_queue] = p_info->queueFamilyIndex;
        d.queue_indices[*p_queue] = p_info->queueIndex;
    }
}

// Waits until everything submitted to `queue` so far has completed (an empty submission's fence).
bool wait_for_queue(DeviceState& d, VkQueue queue, std::string& why) {
    auto create_fence = (PFN_vkCreateFence)d.next.GetDeviceProcAddr(d.device, "vkCreateFence");
    auto destroy_fence = (PFN_vkDestroyFence)d.next.GetDeviceProcAddr(d.device, "vkDestroyFence");
    auto wait_for_fences =
        (PFN_vkWaitForFences)d.next.GetDeviceProcAddr(d.device, "vkWaitForFences");
    if (!create_fence || !destroy_fence || !wait_for_fences) {
        why = "the driver has no fence functions";
        return false;
    }
    VkFenceCreateInfo info{VK_STRUCTURE_TYPE_FENCE_CREATE_INFO, nullptr, 0};
    VkFence fence;
    if (create_fence(d.device, &info, nullptr, &fence) != VK_SUCCESS) {
        why = "vkCreateFence failed";
        return false;
    }
    VkResult result = d.next.QueueSubmit(queue, 0, nullptr, fence);
    if (result == VK_SUCCESS)
        result = wait_for_fences(d.device, 1, &fence, VK_TRUE, 30'000'000'000ull);
    if (result != VK_SUCCESS) {
        why = "waiting for the submission failed with VkResult " + std::to_string(int(result));
        return false;  // the fence may still be pending: leak it rather than destroy it in use
    }
    destroy_fence(d.device, fence, nullptr);
    return true;
}

// One top level's rays, traced by the NV pipeline or (KHR top levels) the ray-query shader;
// recorded as a RayQueryCheck.
void check_top_level(DeviceState& d, const NvRayTracerContext& context, uint64_t top_level,
                     uint64_t submission_index, uint32_t ray_count) {
    const auto started = std::chrono::steady_clock::now();
    const bool khr = d.nv_scene.is_khr_top_level(top_level);
    std::string why;
    if (khr ? !d.ray_query_enabled : !d.nv_ray_tracing_enabled) {
        log_message(LogLevel::kError, "ray check of top level 0x%llx skipped: %s",
                    (unsigned long long)top_level,
                    khr ? "the device has no VK_KHR_ray_query with rayQuery enabled (the layer "
                          "enables it at vkCreateDevice where the device supports it)"
                        : "the device was created without VK_NV_ray_tracing");
        return;
    }
    RayCheckRecord record;
    record.acceleration_structure = top_level;
    record.submission_index = submission_index;
    record.label = khr ? kKhrRayCheckRule : kNvRayCheckRule;
    NvTraceScene scene;
    if (!d.nv_scene.prepare(top_level, ray_count, scene, record.rays, record.device_handle, why)) {
        log_message(LogLevel::kError, "ray check of top level 0x%llx skipped: %s",
                    (unsigned long long)top_level, why.c_str());
        return;
    }
    const bool traced = khr ? trace_rays_khr(context, (VkAccelerationStructureKHR)top_level, scene,
                                             record.rays, record.hits, why)
                            : trace_rays_nv(context, (VkAccelerationStructureNV)top_level, scene,
                                            record.rays, record.hits, why);
    if (!traced) {
        log_message(LogLevel::kError, "ray check of top level 0x%llx failed: %s",
                    (unsigned long long)top_level, why.c_str());
        return;
    }
    if (khr) d.nv_scene.to_cluster_geometry_indices(top_level, record.hits);
    size_t hits = 0;
    for (const NvRayHit& h : record.hits) hits += h.hit != 0;
    const double ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - started)
            .count();
    log_message(LogLevel::kInfo,
                "ray check of %s top level 0x%llx after submission %llu: %zu rays, %zu hits, "
                "%.2f ms",
                khr ? "KHR" : "NV", (unsigned long long)top_level,
                (unsigned long long)submission_index, record.rays.size(), hits, ms);
    d.sink->ray_query_checked(record);
}

}  // namespace

void run_ray_checks(DeviceState& d, VkQueue queue, uint64_t submission_index,
                    const std::vector<uint64_t>& top_levels) {
    const uint32_t ray_count = layer_config().ray_check_rays;
    if (ray_count == 0 || top_levels.empty() || !d.sink) return;
    if (!d.nv_ray_tracing_enabled && !d.ray_query_enabled) {
        log_message(LogLevel::kError,
                    "ray check skipped: the device was created without VK_NV_ray_tracing and "
                    "without VK_KHR_ray_query");
        return;
    }
    uint32_t family;
    {
        std::lock_guard lock(d.queues_mutex);
        auto it = d.queue_families.find(queue);
        if (it == d.queue_families.end()) {
            log_message(LogLevel::kError,
                        "ray check skipped: the queue's family is unknown (queue not from "
                        "vkGetDeviceQueue)");
            return;
        }
        family = it->second;
    }
    std::string why;
    // The worker reads each build's inputs at its pause; once the queue is idle every pause of
    // this submission was handled, so the scene model holds what the builds read.
    if (!wait_for_queue(d, queue, why)) {
        log_message(LogLevel::kError, "ray check after submission %llu skipped: %s",
                    (unsigned long long)submission_index, why.c_str());
        return;
    }
    NvRayTracerContext context;
    context.device = d.device;
    context.queue = queue;
    context.queue_family_index = family;
    context.get_device_proc_addr = d.next.GetDeviceProcAddr;
    context.memory_properties = d.memory_properties;
    context.ray_tracing_properties = d.ray_tracing_properties_nv;
    context.set_command_buffer_dispatch = true;
    for (uint64_t top_level : top_levels)
        check_top_level(d, context, top_level, submission_index, ray_count);
}

PFN_vkVoidFunction acceleration_structure_hook(const char* name) {
#define HOOK(fn) \
    { "vk" #fn, (PFN_vkVoidFunction)fn }
    static const std::map<std::string, PFN_vkVoidFunction, std::less<>> kHooks = {
        HOOK(CreateAccelerationStructureNV),
        HOOK(DestroyAccelerationStructureNV),
        HOOK(BindAccelerationStructureMemoryNV),
        HOOK(GetAccelerationStructureHandleNV),
        HOOK(GetAccelerationStructureMemoryRequirementsNV),
        HOOK(CreateAccelerationStructureKHR),
        HOOK(DestroyAccelerationStructureKHR),
        HOOK(GetAccelerationStructureDeviceAddressKHR),
        HOOK(GetDeviceQueue),
        HOOK(GetDeviceQueue2),
    };
#undef HOOK
    auto it = kHooks.find(name);
    return it == kHooks.end() ? nullptr : it->second;
}

}  // namespace clastrace::capture
