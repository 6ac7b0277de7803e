// SPDX-License-Identifier: Apache-2.0
// The commands that read acceleration structures (issue 20): vkCmdTraceRays* are recorded as
// TraceRaysCommand, with the structures their bound sets, pushed descriptors and push constants
// reach; ray-query dispatches and draws ask `reachable_acceleration_structures` the same way
// (layer_commands.cpp). Also the acceleration-structure address registry, the descriptors'
// acceleration-structure writes, push descriptors and push constants.
#include "command_buffer_log.h"
#include "layer_state.h"

#include <algorithm>
#include <atomic>
#include <cstring>
#include <map>
#include <set>
#include <tuple>
#include <string>

namespace clastrace::capture {
namespace {

using Source = ReachableAccelerationStructure::Source;

DeviceState& device_of(VkCommandBuffer cb) { return *find_device(dispatch_key(cb)); }

std::shared_ptr<CommandBufferLog> log_of(DeviceState& d, VkCommandBuffer cb) {
    return command_buffer_log_of(d, cb);
}

// The handles of an acceleration-structure write (KHR or NV, from its pNext), or none.
std::vector<std::pair<uint64_t, bool>> written_structures(const VkWriteDescriptorSet& write) {
    std::vector<std::pair<uint64_t, bool>> out;  // (handle, khr)
    for (auto* next = static_cast<const VkBaseInStructure*>(write.pNext); next;
         next = next->pNext) {
        if (next->sType == VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET_ACCELERATION_STRUCTURE_KHR) {
            auto* khr = reinterpret_cast<const VkWriteDescriptorSetAccelerationStructureKHR*>(next);
            for (uint32_t i = 0; i < khr->accelerationStructureCount; ++i)
                out.push_back({handle_id(khr->pAccelerationStructures[i]), true});
        } else if (next->sType ==
                   VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET_ACCELERATION_STRUCTURE_NV) {
            auto* nv = reinterpret_cast<const VkWriteDescriptorSetAccelerationStructureNV*>(next);
            for (uint32_t i = 0; i < nv->accelerationStructureCount; ++i)
                out.push_back({handle_id(nv->pAccelerationStructures[i]), false});
        }
    }
    return out;
}

// A push descriptor cannot be dynamic: plain storage and uniform buffers only.
bool is_buffer_write(const VkWriteDescriptorSet& write) {
    return (write.descriptorType == VK_DESCRIPTOR_TYPE_STORAGE_BUFFER ||
            write.descriptorType == VK_DESCRIPTOR_TYPE_UNIFORM_BUFFER) &&
           write.pBufferInfo;
}

bool writes_acceleration_structures(const VkWriteDescriptorSet& write) {
    return write.descriptorType == VK_DESCRIPTOR_TYPE_ACCELERATION_STRUCTURE_KHR ||
           write.descriptorType == VK_DESCRIPTOR_TYPE_ACCELERATION_STRUCTURE_NV;
}

// The descriptors of an acceleration-structure `write`, with `source`; `set` left 0.
std::vector<ReachableAccelerationStructure> structures_of_write(DeviceState& d,
                                                                const VkWriteDescriptorSet& write,
                                                                Source source) {
    std::vector<ReachableAccelerationStructure> out;
    const auto handles = written_structures(write);
    for (uint32_t i = 0; i < write.descriptorCount && i < handles.size(); ++i) {
        ReachableAccelerationStructure r;
        r.binding = write.dstBinding;
        r.array_element = write.dstArrayElement + i;
        r.source = source;
        r.acceleration_structure = handles[i].first;
        r.address = acceleration_structure_address(d, handles[i].first, handles[i].second);
        out.push_back(r);
    }
    return out;
}

// 8-byte values in the push constants equal to a known KHR address. Scanned at every 4-byte
// offset: scalar block layout lets a uint64_t member sit there.
void add_push_constant_addresses(DeviceState& d, const std::vector<uint8_t>& bytes,
                                 std::vector<ReachableAccelerationStructure>& out) {
    if (bytes.size() < sizeof(uint64_t)) return;
    std::lock_guard lock(d.acceleration_structure_addresses_mutex);
    if (d.acceleration_structures_by_address.empty()) return;
    for (size_t offset = 0; offset + sizeof(uint64_t) <= bytes.size(); offset += 4) {
        uint64_t value = 0;
        std::memcpy(&value, bytes.data() + offset, sizeof value);
        if (value == 0) continue;
        auto it = d.acceleration_structures_by_address.find(value);
        if (it == d.acceleration_structures_by_address.end()) continue;
        ReachableAccelerationStructure r;
        r.array_element = uint32_t(offset);  // the byte offset in the push constants
        r.source = Source::kPushConstants;
        r.acceleration_structure = it->second;
        r.address = value;
        out.push_back(r);
    }
}

// ---- Push constants and push descriptors ----------------------------------------------------

VKAPI_ATTR void VKAPI_CALL CmdPushConstants(VkCommandBuffer cb, VkPipelineLayout layout,
                                            VkShaderStageFlags stages, uint32_t offset,
                                            uint32_t size, const void* values) {
    DeviceState& d = device_of(cb);
    d.next.CmdPushConstants(cb, layout, stages, offset, size, values);
    if (!d.sink || !values) return;
    auto log = log_of(d, cb);
    if (log->push_constants.size() < size_t(offset) + size)
        log->push_constants.resize(size_t(offset) + size);
    std::memcpy(log->push_constants.data() + offset, values, size);
}

VKAPI_ATTR void VKAPI_CALL CmdPushDescriptorSetKHR(VkCommandBuffer cb,
                                                   VkPipelineBindPoint bind_point,
                                                   VkPipelineLayout layout, uint32_t set,
                                                   uint32_t write_count,
                                                   const VkWriteDescriptorSet* writes) {
    DeviceState& d = device_of(cb);
    d.next.CmdPushDescriptorSetKHR(cb, bind_point, layout, set, write_count, writes);
    for (uint32_t w = 0; w < write_count; ++w)
        track_pushed_descriptor_write(d, cb, bind_point, set, writes[w]);
}

// ---- VK_KHR_maintenance6: the info-struct forms, each turned into its 1.0 form ---------------
// One call per bind point its stage flags name, as the extension defines them; a chain on the
// info (a pipeline layout given by VkPipelineLayoutCreateInfo) has no 1.0 form: forwarded as is,
// and not followed.

std::vector<VkPipelineBindPoint> bind_points_of(VkShaderStageFlags stages) {
    constexpr VkShaderStageFlags kGraphics =
        VK_SHADER_STAGE_ALL_GRAPHICS | VK_SHADER_STAGE_TASK_BIT_EXT | VK_SHADER_STAGE_MESH_BIT_EXT;
    constexpr VkShaderStageFlags kRays =
        VK_SHADER_STAGE_RAYGEN_BIT_KHR | VK_SHADER_STAGE_ANY_HIT_BIT_KHR |
        VK_SHADER_STAGE_CLOSEST_HIT_BIT_KHR | VK_SHADER_STAGE_MISS_BIT_KHR |
        VK_SHADER_STAGE_INTERSECTION_BIT_KHR | VK_SHADER_STAGE_CALLABLE_BIT_KHR;
    std::vector<VkPipelineBindPoint> out;
    if (stages & VK_SHADER_STAGE_COMPUTE_BIT) out.push_back(VK_PIPELINE_BIND_POINT_COMPUTE);
    if (stages & kGraphics) out.push_back(VK_PIPELINE_BIND_POINT_GRAPHICS);
    if (stages & kRays) out.push_back(VK_PIPELINE_BIND_POINT_RAY_TRACING_KHR);
    return out;
}

void say_chained_info_not_followed(const char* entry_point) {
    static std::atomic<bool> said{false};
    if (!said.exchange(true))
        log_message(LogLevel::kInfo,
                    "%s with a pNext chain (a pipeline layout given by its create info): "
                    "forwarded as is; the acceleration structures it binds are not followed",
                    entry_point);
}

VKAPI_ATTR void VKAPI_CALL CmdBindDescriptorSets2KHR(VkCommandBuffer cb,
                                                     const VkBindDescriptorSetsInfoKHR* info) {
    DeviceState& d = device_of(cb);
    if (info->pNext) {
        say_chained_info_not_followed("vkCmdBindDescriptorSets2KHR");
        return d.next.CmdBindDescriptorSets2KHR(cb, info);
    }
    // The layer's own vkCmdBindDescriptorSets (layer_commands.cpp): it forwards and follows.
    const auto bind =
        reinterpret_cast<PFN_vkCmdBindDescriptorSets>(command_hook("vkCmdBindDescriptorSets"));
    for (VkPipelineBindPoint bind_point : bind_points_of(info->stageFlags))
        bind(cb, bind_point, info->layout, info->firstSet, info->descriptorSetCount,
             info->pDescriptorSets, info->dynamicOffsetCount, info->pDynamicOffsets);
}

VKAPI_ATTR void VKAPI_CALL CmdPushConstants2KHR(VkCommandBuffer cb,
                                                const VkPushConstantsInfoKHR* info) {
    if (info->pNext) {
        say_chained_info_not_followed("vkCmdPushConstants2KHR");
        return device_of(cb).next.CmdPushConstants2KHR(cb, info);
    }
    CmdPushConstants(cb, info->layout, info->stageFlags, info->offset, info->size, info->pValues);
}

VKAPI_ATTR void VKAPI_CALL CmdPushDescriptorSet2KHR(VkCommandBuffer cb,
                                                    const VkPushDescriptorSetInfoKHR* info) {
    if (info->pNext) {
        say_chained_info_not_followed("vkCmdPushDescriptorSet2KHR");
        return device_of(cb).next.CmdPushDescriptorSet2KHR(cb, info);
    }
    for (VkPipelineBindPoint bind_point : bind_points_of(info->stageFlags))
        CmdPushDescriptorSetKHR(cb, bind_point, info->layout, info->set, info->descriptorWriteCount,
                                info->pDescriptorWrites);
}

VKAPI_ATTR void VKAPI_CALL CmdPushDescriptorSetWithTemplate2KHR(
    VkCommandBuffer cb, const VkPushDescriptorSetWithTemplateInfoKHR* info) {
    if (info->pNext) {
        say_chained_info_not_followed("vkCmdPushDescriptorSetWithTemplate2KHR");
        return device_of(cb).next.CmdPushDescriptorSetWithTemplate2KHR(cb, info);
    }
    // The template names its bind point (descriptor_templates.cpp follows it).
    const auto push = reinterpret_cast<PFN_vkCmdPushDescriptorSetWithTemplateKHR>(
        descriptor_template_hook("vkCmdPushDescriptorSetWithTemplateKHR"));
    push(cb, info->descriptorUpdateTemplate, info->layout, info->set, info->pData);
}

// ---- Rays -----------------------------------------------------------------------------------

// The command for the bound ray-tracing pipeline, with what it can reach.
TraceRaysCommand trace_rays_command(DeviceState& d, const CommandBufferLog& log,
                                    const char* entry_point) {
    TraceRaysCommand c;
    c.pipeline = log.ray_tracing_pipeline;
    c.entry_point = entry_point;
    c.acceleration_structures =
        reachable_acceleration_structures(d, log, VK_PIPELINE_BIND_POINT_RAY_TRACING_KHR);
    c.storage_buffers = bound_storage_buffers(d, log.ray_tracing_sets);
    c.may_write_device_addresses = address_writing_stages(d, log.ray_tracing_pipeline) != 0;
    return c;
}

void set_tables(TraceRaysCommand& c, const VkStridedDeviceAddressRegionKHR* raygen,
                const VkStridedDeviceAddressRegionKHR* miss,
                const VkStridedDeviceAddressRegionKHR* hit,
                const VkStridedDeviceAddressRegionKHR* callable) {
    const VkStridedDeviceAddressRegionKHR* regions[4] = {raygen, miss, hit, callable};
    for (int i = 0; i < 4; ++i)
        if (regions[i]) c.shader_binding_tables[i] = *regions[i];
}

// The indirect forms: a pause before the rays reads their parameters as the device will (the
// application's barriers make them visible to the rays, and so to the pause's host read).
void pause_for_indirect_parameters(DeviceState& d, VkCommandBuffer cb, CommandBufferLog& log,
                                   TraceRaysCommand& c) {
    if (!d.capturing_now() || !c.indirect_address || !c.indirect_size) return;
    c.pause_id = ++d.pause_counter;
    PausePoint before;
    before.pause_id = c.pause_id;
    before.trace_rays = std::make_shared<const TraceRaysCommand>(c);
    record_pause_before_command(d, cb, log, before);
}

void record_trace_rays(VkCommandBuffer cb, DeviceState& d,
                       const std::function<void(TraceRaysCommand&)>& fill,
                       const char* entry_point) {
    if (!d.sink) return;
    auto log = log_of(d, cb);
    TraceRaysCommand c = trace_rays_command(d, *log, entry_point);
    fill(c);
    pause_for_indirect_parameters(d, cb, *log, c);
    log->recorded.commands.push_back(std::move(c));
}

VKAPI_ATTR void VKAPI_CALL CmdTraceRaysKHR(VkCommandBuffer cb,
                                           const VkStridedDeviceAddressRegionKHR* raygen,
                                           const VkStridedDeviceAddressRegionKHR* miss,
                                           const VkStridedDeviceAddressRegionKHR* hit,
                                           const VkStridedDeviceAddressRegionKHR* callable,
                                           uint32_t width, uint32_t height, uint32_t depth) {
    DeviceState& d = device_of(cb);
    d.next.CmdTraceRaysKHR(cb, raygen, miss, hit, callable, width, height, depth);
    record_trace_rays(
        cb, d,
        [&](TraceRaysCommand& c) {
            set_tables(c, raygen, miss, hit, callable);
            c.width = width;
            c.height = height;
            c.depth = depth;
        },
        "vkCmdTraceRaysKHR");
}

VKAPI_ATTR void VKAPI_CALL CmdTraceRaysIndirectKHR(VkCommandBuffer cb,
                                                   const VkStridedDeviceAddressRegionKHR* raygen,
                                                   const VkStridedDeviceAddressRegionKHR* miss,
                                                   const VkStridedDeviceAddressRegionKHR* hit,
                                                   const VkStridedDeviceAddressRegionKHR* callable,
                                                   VkDeviceAddress indirect_address) {
    DeviceState& d = device_of(cb);
    // Recorded first: its pause must come before the rays in the command buffer.
    record_trace_rays(
        cb, d,
        [&](TraceRaysCommand& c) {
            set_tables(c, raygen, miss, hit, callable);
            c.indirect_address = indirect_address;
            c.indirect_size = sizeof(VkTraceRaysIndirectCommandKHR);
        },
        "vkCmdTraceRaysIndirectKHR");
    d.next.CmdTraceRaysIndirectKHR(cb, raygen, miss, hit, callable, indirect_address);
}

VKAPI_ATTR void VKAPI_CALL CmdTraceRaysIndirect2KHR(VkCommandBuffer cb,
                                                    VkDeviceAddress indirect_address) {
    DeviceState& d = device_of(cb);
    record_trace_rays(  // first, as vkCmdTraceRaysIndirectKHR
        cb, d,
        [&](TraceRaysCommand& c) {
            c.indirect_address = indirect_address;
            c.indirect_size = sizeof(VkTraceRaysIndirectCommand2KHR);
        },
        "vkCmdTraceRaysIndirect2KHR");
    d.next.CmdTraceRaysIndirect2KHR(cb, indirect_address);
}

// NV names its tables by buffer and offset: the region's address is the buffer's address plus
// the offset when the application asked for the buffer's address, else 0; sizes are unknown.
VkStridedDeviceAddressRegionKHR nv_region(DeviceState& d, VkBuffer buffer, VkDeviceSize offset,
                                          VkDeviceSize stride) {
    VkStridedDeviceAddressRegionKHR r{0, stride, 0};
    if (auto b = d.memory_map.buffer(handle_id(buffer)); b && b->address)
        r.deviceAddress = b->address + offset;
    return r;
}

VKAPI_ATTR void VKAPI_CALL CmdTraceRaysNV(
    VkCommandBuffer cb, VkBuffer raygen, VkDeviceSize raygen_offset, VkBuffer miss,
    VkDeviceSize miss_offset, VkDeviceSize miss_stride, VkBuffer hit, VkDeviceSize hit_offset,
    VkDeviceSize hit_stride, VkBuffer callable, VkDeviceSize callable_offset,
    VkDeviceSize callable_stride, uint32_t width, uint32_t height, uint32_t depth) {
    DeviceState& d = device_of(cb);
    d.next.CmdTraceRaysNV(cb, raygen, raygen_offset, miss, miss_offset, miss_stride, hit,
                          hit_offset, hit_stride, callable, callable_offset, callable_stride, width,
                          height, depth);
    record_trace_rays(
        cb, d,
        [&](TraceRaysCommand& c) {
            c.shader_binding_tables[0] = nv_region(d, raygen, raygen_offset, 0);
            c.shader_binding_tables[1] = nv_region(d, miss, miss_offset, miss_stride);
            c.shader_binding_tables[2] = nv_region(d, hit, hit_offset, hit_stride);
            c.shader_binding_tables[3] = nv_region(d, callable, callable_offset, callable_stride);
            c.width = width;
            c.height = height;
            c.depth = depth;
        },
        "vkCmdTraceRaysNV");
}

}  // namespace

// ---- The address registry -------------------------------------------------------------------

VkDeviceAddress acceleration_structure_address(DeviceState& d, uint64_t handle, bool khr) {
    if (!handle) return 0;
    {
        std::lock_guard lock(d.acceleration_structure_addresses_mutex);
        auto it = d.acceleration_structure_addresses.find(handle);
        if (it != d.acceleration_structure_addresses.end()) return it->second;
    }
    // Asking for a KHR structure's address has no side effect: the layer asks itself, once.
    if (!khr || !d.next.GetAccelerationStructureDeviceAddressKHR) return 0;
    VkAccelerationStructureDeviceAddressInfoKHR info{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_DEVICE_ADDRESS_INFO_KHR, nullptr,
        reinterpret_cast<VkAccelerationStructureKHR>(handle)};
    const VkDeviceAddress address =
        d.next.GetAccelerationStructureDeviceAddressKHR(d.device, &info);
    remember_acceleration_structure_address(d, handle, address);
    return address;
}

void remember_acceleration_structure_address(DeviceState& d, uint64_t handle,
                                             VkDeviceAddress address) {
    if (!handle || !address) return;
    std::lock_guard lock(d.acceleration_structure_addresses_mutex);
    d.acceleration_structure_addresses[handle] = address;
    d.acceleration_structures_by_address[address] = handle;
}

void forget_acceleration_structure_address(DeviceState& d, uint64_t handle) {
    std::lock_guard lock(d.acceleration_structure_addresses_mutex);
    auto it = d.acceleration_structure_addresses.find(handle);
    if (it == d.acceleration_structure_addresses.end()) return;
    auto back = d.acceleration_structures_by_address.find(it->second);
    if (back != d.acceleration_structures_by_address.end() && back->second == handle)
        d.acceleration_structures_by_address.erase(back);
    d.acceleration_structure_addresses.erase(it);
}

// ---- Descriptors ----------------------------------------------------------------------------

bool track_acceleration_structure_write(DeviceState& d, const VkWriteDescriptorSet& write,
                                        DescriptorsOfSet& set) {
    if (!writes_acceleration_structures(write)) return false;
    for (uint32_t i = 0; i < write.descriptorCount; ++i)
        set.erase({write.dstBinding, write.dstArrayElement + i});
    for (const ReachableAccelerationStructure& r :
         structures_of_write(d, write, Source::kDescriptorSet))
        set[{r.binding, r.array_element}] = r;
    return true;
}

void track_pushed_descriptor_write(DeviceState& d, VkCommandBuffer cb,
                                   VkPipelineBindPoint bind_point, uint32_t set,
                                   const VkWriteDescriptorSet& write) {
    const int index = bind_point_index(bind_point);
    if (!d.sink || index < 0) return;
    auto log = log_of(d, cb);
    log->sets_at(bind_point)->erase(set);  // a push replaces the set bound there
    auto& pushed = log->pushed_acceleration_structures[index];
    auto& buffers = log->pushed_buffers[index];
    // A push replaces what the same elements held, whatever their type now.
    for (uint32_t i = 0; i < write.descriptorCount; ++i) {
        pushed.erase({set, write.dstBinding, write.dstArrayElement + i});
        buffers.erase({set, write.dstBinding, write.dstArrayElement + i});
    }
    if (is_buffer_write(write)) {
        for (uint32_t i = 0; i < write.descriptorCount; ++i) {
            BoundStorageBuffer b;
            b.set = set;
            b.binding = write.dstBinding;
            b.array_element = write.dstArrayElement + i;
            b.type = write.descriptorType;
            b.buffer = handle_id(write.pBufferInfo[i].buffer);
            b.offset = write.pBufferInfo[i].offset;
            b.range = write.pBufferInfo[i].range;
            buffers[{set, b.binding, b.array_element}] = b;
        }
        return;
    }
    if (!writes_acceleration_structures(write)) return;
    for (ReachableAccelerationStructure r :
         structures_of_write(d, write, Source::kPushDescriptor)) {
        r.set = set;
        pushed[{set, r.binding, r.array_element}] = r;
    }
}

namespace {

// What `bindings` reach now: the acceleration-structure descriptors the bound sets hold at this
// moment, the pushed ones, and push-constant values equal to a known address.
std::vector<ReachableAccelerationStructure> structures_reached(DeviceState& d,
                                                               const ConsumerBindings& bindings) {
    std::vector<ReachableAccelerationStructure> out;
    {
        std::lock_guard lock(d.descriptors_mutex);
        for (const auto& [set_index, bound] : bindings.sets) {
            auto known = d.descriptors.find(bound.first);
            if (known == d.descriptors.end()) continue;
            for (const auto& [key, tracked] : known->second)
                if (const auto* r = std::get_if<ReachableAccelerationStructure>(&tracked)) {
                    out.push_back(*r);
                    out.back().set = set_index;
                }
        }
    }
    for (const auto& [key, r] : bindings.pushed) out.push_back(r);
    add_descriptor_buffer_structures(d, bindings.buffer_sets, out);
    add_push_constant_addresses(d, bindings.push_constants, out);
    add_buffer_structure_addresses(d, bindings, out);
    return out;
}

bool same_structures(const std::vector<ReachableAccelerationStructure>& a,
                     const std::vector<ReachableAccelerationStructure>& b) {
    auto fields = [](const ReachableAccelerationStructure& r) {
        return std::tuple(r.set, r.binding, r.array_element, r.source, r.acceleration_structure,
                          r.address);
    };
    return std::equal(a.begin(), a.end(), b.begin(), b.end(),
                      [&](const auto& x, const auto& y) { return fields(x) == fields(y); });
}

// The reachable structures of a recorded consumer, or null for any other command. The order
// matches the calls of reachable_acceleration_structures (layer_commands.cpp asks for ray-query
// dispatches and draws only; rays always ask).
std::vector<ReachableAccelerationStructure>* consumer_structures(RecordedCommand& command) {
    if (auto* c = std::get_if<DispatchCommand>(&command))
        return c->ray_query ? &c->acceleration_structures : nullptr;
    if (auto* c = std::get_if<DrawCommand>(&command))
        return c->ray_query_stages ? &c->acceleration_structures : nullptr;
    if (auto* c = std::get_if<TraceRaysCommand>(&command)) return &c->acceleration_structures;
    return nullptr;
}

// Reads the structures of `cb`'s consumers again; hands the recording to the sink when one
// changed. Appends the secondaries it executes to `secondaries`.
void refresh_command_buffer(DeviceState& d, uint64_t cb, std::vector<uint64_t>& secondaries) {
    std::shared_ptr<CommandBufferLog> log;
    {
        std::lock_guard lock(d.command_buffers_mutex);
        auto it = d.command_buffers.find(reinterpret_cast<VkCommandBuffer>(cb));
        if (it == d.command_buffers.end()) return;
        log = it->second;
    }
    size_t next = 0;
    bool changed = false;
    for (RecordedCommand& command : log->recorded.commands) {
        if (const auto* execute = std::get_if<ExecuteCommandsCommand>(&command))
            secondaries.insert(secondaries.end(), execute->secondaries.begin(),
                               execute->secondaries.end());
        std::vector<ReachableAccelerationStructure>* recorded = consumer_structures(command);
        if (!recorded || next >= log->consumers.size()) continue;
        std::vector<ReachableAccelerationStructure> now =
            structures_reached(d, log->consumers[next++]);
        if (same_structures(now, *recorded)) continue;
        *recorded = std::move(now);
        changed = true;
    }
    if (changed) d.sink->command_buffer_recorded(log->recorded);
}

}  // namespace

std::vector<ReachableAccelerationStructure> reachable_acceleration_structures(
    DeviceState& d, const CommandBufferLog& log, VkPipelineBindPoint bind_point) {
    const int index = bind_point_index(bind_point);
    if (index < 0) return {};
    ConsumerBindings bindings;
    bindings.bind_point = index;
    bindings.sets = index == 0   ? log.compute_sets
                    : index == 1 ? log.graphics_sets
                                 : log.ray_tracing_sets;
    bindings.pushed = log.pushed_acceleration_structures[index];
    bindings.push_constants = log.push_constants;
    bindings.buffer_sets = descriptor_buffer_sets_at(log, index);
    const uint64_t pipeline = index == 0   ? log.compute_pipeline
                              : index == 1 ? log.graphics_pipeline
                                           : log.ray_tracing_pipeline;
    bindings.search_bound_buffers = converts_structure_addresses_from_memory(d, pipeline);
    if (bindings.search_bound_buffers) bindings.pushed_buffers = log.pushed_buffers[index];
    log.consumers.push_back(std::move(bindings));
    return structures_reached(d, log.consumers.back());
}

void refresh_consumer_structures(DeviceState& d, const SubmissionRecord& record) {
    if (!d.sink) return;
    std::vector<uint64_t> pending;
    for (const SubmitBatch& batch : record.batches)
        pending.insert(pending.end(), batch.command_buffers.begin(), batch.command_buffers.end());
    std::set<uint64_t> done;
    while (!pending.empty()) {
        const uint64_t cb = pending.back();
        pending.pop_back();
        if (done.insert(cb).second) refresh_command_buffer(d, cb, pending);
    }
}

PFN_vkVoidFunction consumer_hook(const char* name) {
#define CLASTRACE_CONSUMER_HOOK(fn) \
    if (std::strcmp(name, "vk" #fn) == 0) return (PFN_vkVoidFunction)fn;
    CLASTRACE_CONSUMER_HOOK(CmdPushConstants)
    CLASTRACE_CONSUMER_HOOK(CmdPushDescriptorSetKHR)
    CLASTRACE_CONSUMER_HOOK(CmdBindDescriptorSets2KHR)
    CLASTRACE_CONSUMER_HOOK(CmdPushConstants2KHR)
    CLASTRACE_CONSUMER_HOOK(CmdPushDescriptorSet2KHR)
    CLASTRACE_CONSUMER_HOOK(CmdPushDescriptorSetWithTemplate2KHR)
    CLASTRACE_CONSUMER_HOOK(CmdTraceRaysKHR)
    CLASTRACE_CONSUMER_HOOK(CmdTraceRaysIndirectKHR)
    CLASTRACE_CONSUMER_HOOK(CmdTraceRaysIndirect2KHR)
    CLASTRACE_CONSUMER_HOOK(CmdTraceRaysNV)
#undef CLASTRACE_CONSUMER_HOOK
    return descriptor_buffer_hook(name);  // VK_EXT_descriptor_buffer
}

}  // namespace clastrace::capture
