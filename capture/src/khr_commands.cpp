// SPDX-License-Identifier: Apache-2.0
// VK_KHR_acceleration_structure in use: builds (direct and indirect), copies (and NV's copy),
// serialization to memory, property queries (and NV's), the results the application reads back,
// and build-size queries. Builds and KHR copies get a pause before them, where the pause worker
// reads every byte they read (khr_input_walker.h); the rest is recorded as called.
#include "clastrace/capture/khr_input_walker.h"
#include "command_buffer_log.h"
#include "layer_state.h"

#include <map>
#include <mutex>
#include <set>
#include <string>

namespace clastrace::capture {
namespace {

// Where each KHR structure lives, and which query pools hold acceleration-structure property
// queries, per device (keyed by its state: handles are only unique within a device).
struct KhrDirectory {
    std::mutex mutex;
    std::map<std::pair<const DeviceState*, uint64_t>, KhrStructureStorage> structures;
    std::set<std::pair<const DeviceState*, uint64_t>> property_pools;
};
KhrDirectory& directory() {
    static KhrDirectory instance;
    return instance;
}

DeviceState& device_of(VkCommandBuffer cb) { return *find_device(dispatch_key(cb)); }

// A pause id when capturing now (the command's and its pause's), else 0.
uint64_t next_pause_id(DeviceState& d) { return d.capturing_now() ? ++d.pause_counter : 0; }

void record_build(VkCommandBuffer cb, std::shared_ptr<BuildAccelerationStructuresKHRCommand> c,
                  const std::function<void()>& forward) {
    DeviceState& d = device_of(cb);
    for (KhrBuildInfo& info : c->infos)
        if (info.info.mode == VK_BUILD_ACCELERATION_STRUCTURE_MODE_UPDATE_KHR)
            info.update_source =
                khr_structure_storage(d, handle_id(info.info.srcAccelerationStructure));
    c->pause_id = next_pause_id(d);
    PausePoint before;
    before.pause_id = c->pause_id;
    before.build_khr = c;
    record_command_with_pause(cb, &before, forward, *c);
}

VKAPI_ATTR void VKAPI_CALL CmdBuildAccelerationStructuresKHR(
    VkCommandBuffer cb, uint32_t info_count,
    const VkAccelerationStructureBuildGeometryInfoKHR* p_infos,
    const VkAccelerationStructureBuildRangeInfoKHR* const* pp_build_range_infos) {
    auto c = std::make_shared<BuildAccelerationStructuresKHRCommand>();
    for (uint32_t i = 0; i < info_count; ++i)
        c->infos.push_back(KhrBuildInfo::copy_of(p_infos[i], pp_build_range_infos[i]));
    record_build(cb, std::move(c), [&] {
        device_of(cb).next.CmdBuildAccelerationStructuresKHR(cb, info_count, p_infos,
                                                             pp_build_range_infos);
    });
}

VKAPI_ATTR void VKAPI_CALL CmdBuildAccelerationStructuresIndirectKHR(
    VkCommandBuffer cb, uint32_t info_count,
    const VkAccelerationStructureBuildGeometryInfoKHR* p_infos,
    const VkDeviceAddress* p_indirect_device_addresses, const uint32_t* p_indirect_strides,
    const uint32_t* const* pp_max_primitive_counts) {
    auto c = std::make_shared<BuildAccelerationStructuresKHRCommand>();
    c->indirect = true;
    for (uint32_t i = 0; i < info_count; ++i) {
        KhrBuildInfo info = KhrBuildInfo::copy_of(p_infos[i], nullptr);
        info.indirect_address = p_indirect_device_addresses[i];
        info.indirect_stride = p_indirect_strides[i];
        info.max_primitive_counts.assign(pp_max_primitive_counts[i],
                                         pp_max_primitive_counts[i] + p_infos[i].geometryCount);
        c->infos.push_back(std::move(info));
    }
    record_build(cb, std::move(c), [&] {
        device_of(cb).next.CmdBuildAccelerationStructuresIndirectKHR(cb, info_count, p_infos,
                                                                     p_indirect_device_addresses,
                                                                     p_indirect_strides,
                                                                     pp_max_primitive_counts);
    });
}

void record_copy(VkCommandBuffer cb, std::shared_ptr<CopyAccelerationStructureCommand> c,
                 const std::function<void()>& forward) {
    DeviceState& d = device_of(cb);
    if (!c->khr) {  // an NV structure's memory is opaque to the layer: nothing to read
        record_command_with_pause(cb, nullptr, forward, *c);
        return;
    }
    c->source = khr_structure_storage(d, c->src);
    c->pause_id = next_pause_id(d);
    PausePoint before;
    before.pause_id = c->pause_id;
    before.copy_acceleration_structure = c;
    record_command_with_pause(cb, &before, forward, *c);
}

VKAPI_ATTR void VKAPI_CALL CmdCopyAccelerationStructureKHR(
    VkCommandBuffer cb, const VkCopyAccelerationStructureInfoKHR* p_info) {
    auto c = std::make_shared<CopyAccelerationStructureCommand>();
    c->src = handle_id(p_info->src);
    c->dst = handle_id(p_info->dst);
    c->mode = p_info->mode;
    record_copy(cb, std::move(c),
                [&] { device_of(cb).next.CmdCopyAccelerationStructureKHR(cb, p_info); });
}

VKAPI_ATTR void VKAPI_CALL CmdCopyAccelerationStructureNV(VkCommandBuffer cb,
                                                          VkAccelerationStructureNV dst,
                                                          VkAccelerationStructureNV src,
                                                          VkCopyAccelerationStructureModeNV mode) {
    auto c = std::make_shared<CopyAccelerationStructureCommand>();
    c->khr = false;
    c->src = handle_id(src);
    c->dst = handle_id(dst);
    c->mode = mode;
    record_copy(cb, std::move(c),
                [&] { device_of(cb).next.CmdCopyAccelerationStructureNV(cb, dst, src, mode); });
}

VKAPI_ATTR void VKAPI_CALL CmdCopyAccelerationStructureToMemoryKHR(
    VkCommandBuffer cb, const VkCopyAccelerationStructureToMemoryInfoKHR* p_info) {
    auto c = std::make_shared<CopyAccelerationStructureCommand>();
    c->to_memory = true;
    c->src = handle_id(p_info->src);
    c->dst_address = p_info->dst.deviceAddress;
    c->mode = p_info->mode;
    record_copy(cb, std::move(c),
                [&] { device_of(cb).next.CmdCopyAccelerationStructureToMemoryKHR(cb, p_info); });
}

void record_property_write(VkCommandBuffer cb, WriteAccelerationStructuresPropertiesCommand c,
                           const std::function<void()>& forward) {
    DeviceState& d = device_of(cb);
    {
        KhrDirectory& dir = directory();
        std::lock_guard lock(dir.mutex);
        dir.property_pools.insert({&d, c.query_pool});
    }
    record_command_with_pause(cb, nullptr, forward, std::move(c));
}

VKAPI_ATTR void VKAPI_CALL CmdWriteAccelerationStructuresPropertiesKHR(
    VkCommandBuffer cb, uint32_t count, const VkAccelerationStructureKHR* p_structures,
    VkQueryType query_type, VkQueryPool query_pool, uint32_t first_query) {
    WriteAccelerationStructuresPropertiesCommand c;
    for (uint32_t i = 0; i < count; ++i)
        c.acceleration_structures.push_back(handle_id(p_structures[i]));
    c.query_type = query_type;
    c.query_pool = handle_id(query_pool);
    c.first_query = first_query;
    record_property_write(cb, std::move(c), [&] {
        device_of(cb).next.CmdWriteAccelerationStructuresPropertiesKHR(cb, count, p_structures,
                                                                       query_type, query_pool,
                                                                       first_query);
    });
}

VKAPI_ATTR void VKAPI_CALL CmdWriteAccelerationStructuresPropertiesNV(
    VkCommandBuffer cb, uint32_t count, const VkAccelerationStructureNV* p_structures,
    VkQueryType query_type, VkQueryPool query_pool, uint32_t first_query) {
    WriteAccelerationStructuresPropertiesCommand c;
    c.khr = false;
    for (uint32_t i = 0; i < count; ++i)
        c.acceleration_structures.push_back(handle_id(p_structures[i]));
    c.query_type = query_type;
    c.query_pool = handle_id(query_pool);
    c.first_query = first_query;
    record_property_write(cb, std::move(c), [&] {
        device_of(cb).next.CmdWriteAccelerationStructuresPropertiesNV(cb, count, p_structures,
                                                                      query_type, query_pool,
                                                                      first_query);
    });
}

// Each query's words as 64-bit values: 32-bit results are widened, an availability word kept.
std::vector<uint64_t> query_values(uint32_t count, size_t data_size, const void* data,
                                   VkDeviceSize stride, VkQueryResultFlags flags) {
    const bool wide = flags & VK_QUERY_RESULT_64_BIT;
    const uint32_t words = (flags & VK_QUERY_RESULT_WITH_AVAILABILITY_BIT) ? 2 : 1;
    const size_t word = wide ? 8 : 4;
    std::vector<uint64_t> values;
    for (uint32_t q = 0; q < count; ++q)
        for (uint32_t w = 0; w < words; ++w) {
            const size_t at = size_t(q * stride) + w * word;
            if (at + word > data_size) return values;
            uint64_t value = 0;
            if (wide)
                std::memcpy(&value, static_cast<const uint8_t*>(data) + at, 8);
            else {
                uint32_t narrow;
                std::memcpy(&narrow, static_cast<const uint8_t*>(data) + at, 4);
                value = narrow;
            }
            values.push_back(value);
        }
    return values;
}

VKAPI_ATTR VkResult VKAPI_CALL GetQueryPoolResults(VkDevice device, VkQueryPool pool,
                                                   uint32_t first_query, uint32_t query_count,
                                                   size_t data_size, void* p_data,
                                                   VkDeviceSize stride, VkQueryResultFlags flags) {
    DeviceState& d = *find_device(dispatch_key(device));
    const VkResult result = d.next.GetQueryPoolResults(device, pool, first_query, query_count,
                                                       data_size, p_data, stride, flags);
    if (!d.sink) return result;
    {
        KhrDirectory& dir = directory();
        std::lock_guard lock(dir.mutex);
        if (!dir.property_pools.count({&d, handle_id(pool)})) return result;
    }
    QueryPoolResultsRecord r;
    r.query_pool = handle_id(pool);
    r.first_query = first_query;
    r.values = query_values(query_count, data_size, p_data, stride, flags);
    r.result = result;
    d.sink->query_pool_results_read(r);
    return result;
}

// A destroyed pool's handle may come back for the next pool (lavapipe reuses them at once): a
// timestamp pool must not inherit the property-query mark.
VKAPI_ATTR void VKAPI_CALL DestroyQueryPool(VkDevice device, VkQueryPool pool,
                                            const VkAllocationCallbacks* p_allocator) {
    DeviceState& d = *find_device(dispatch_key(device));
    {
        KhrDirectory& dir = directory();
        std::lock_guard lock(dir.mutex);
        dir.property_pools.erase({&d, handle_id(pool)});
    }
    d.next.DestroyQueryPool(device, pool, p_allocator);
}

VKAPI_ATTR void VKAPI_CALL GetAccelerationStructureBuildSizesKHR(
    VkDevice device, VkAccelerationStructureBuildTypeKHR build_type,
    const VkAccelerationStructureBuildGeometryInfoKHR* p_build_info,
    const uint32_t* p_max_primitive_counts, VkAccelerationStructureBuildSizesInfoKHR* p_size_info) {
    DeviceState& d = *find_device(dispatch_key(device));
    d.next.GetAccelerationStructureBuildSizesKHR(device, build_type, p_build_info,
                                                 p_max_primitive_counts, p_size_info);
    if (!d.sink) return;
    KhrBuildSizesQuery q;
    q.build_type = build_type;
    q.info = KhrBuildInfo::copy_of(*p_build_info, nullptr);
    if (p_max_primitive_counts)
        q.max_primitive_counts.assign(p_max_primitive_counts,
                                      p_max_primitive_counts + p_build_info->geometryCount);
    q.answer = *p_size_info;
    q.answer.pNext = nullptr;
    d.sink->khr_build_sizes_queried(q);
}

}  // namespace

void remember_khr_structure(DeviceState& device, const KhrStructureStorage& storage) {
    KhrDirectory& dir = directory();
    std::lock_guard lock(dir.mutex);
    dir.structures[{&device, storage.acceleration_structure}] = storage;
}

KhrStructureStorage khr_structure_storage(const DeviceState& device,
                                          uint64_t acceleration_structure) {
    if (acceleration_structure == 0) return {};
    KhrDirectory& dir = directory();
    std::lock_guard lock(dir.mutex);
    auto it = dir.structures.find({&device, acceleration_structure});
    if (it == dir.structures.end()) return {acceleration_structure};
    return it->second;
}

void forget_khr_structure(DeviceState& device, uint64_t acceleration_structure) {
    KhrDirectory& dir = directory();
    std::lock_guard lock(dir.mutex);
    dir.structures.erase({&device, acceleration_structure});
}

void forget_khr_device(const DeviceState& device) {
    KhrDirectory& dir = directory();
    std::lock_guard lock(dir.mutex);
    std::erase_if(dir.structures, [&](const auto& e) { return e.first.first == &device; });
    std::erase_if(dir.property_pools, [&](const auto& e) { return e.first == &device; });
}

PFN_vkVoidFunction khr_acceleration_structure_hook(const char* name) {
#define HOOK(fn) \
    { "vk" #fn, (PFN_vkVoidFunction)fn }
    static const std::map<std::string, PFN_vkVoidFunction, std::less<>> kHooks = {
        HOOK(CmdBuildAccelerationStructuresKHR),
        HOOK(CmdBuildAccelerationStructuresIndirectKHR),
        HOOK(CmdCopyAccelerationStructureKHR),
        HOOK(CmdCopyAccelerationStructureNV),
        HOOK(CmdCopyAccelerationStructureToMemoryKHR),
        HOOK(CmdWriteAccelerationStructuresPropertiesKHR),
        HOOK(CmdWriteAccelerationStructuresPropertiesNV),
        HOOK(GetQueryPoolResults),
        HOOK(DestroyQueryPool),
        HOOK(GetAccelerationStructureBuildSizesKHR),
    };
#undef HOOK
    auto it = kHooks.find(name);
    return it == kHooks.end() ? nullptr : it->second;
}

}  // namespace clastrace::capture
