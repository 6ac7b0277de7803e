// SPDX-License-Identifier: MIT
// VK_LAYER_CLASTRACE_standin_driver: the loader entry points and the Vulkan calls the stand-in
// answers or watches (README.md). Memory is mapped once at allocation so the builds, run on
// the host while the queue waits on an event, can read and write it.
#include "standin_build.h"
#include "standin_layout.h"

#include <clastrace/engine/properties.h>
#include <vulkan/vk_layer.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstring>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <unordered_map>
#include <vector>

namespace clastrace::standin {
namespace {

constexpr const char* kLayerName = "VK_LAYER_CLASTRACE_standin_driver";

void* dispatch_key(const void* handle) { return *static_cast<void* const*>(handle); }

// The calls below, resolved while the instance is created (the loader answers differently
// once vkCreateInstance returned).
struct InstanceState {
    PFN_vkGetInstanceProcAddr next_gipa = nullptr;
    VkInstance instance = VK_NULL_HANDLE;
    PFN_vkEnumerateDeviceExtensionProperties enumerate_device_extensions = nullptr;
    PFN_vkGetPhysicalDeviceFeatures2 get_features2 = nullptr;
    PFN_vkGetPhysicalDeviceProperties2 get_properties2 = nullptr;
    PFN_vkGetPhysicalDeviceMemoryProperties get_memory_properties = nullptr;
    PFN_vkDestroyInstance destroy_instance = nullptr;
};

struct MemoryState {
    uint8_t* host = nullptr;  // mapped for the memory's whole life; nullptr: not host-visible
};

struct BufferState {
    VkDeviceSize size = 0;
    VkBufferUsageFlags usage = 0;
    VkDeviceMemory memory = VK_NULL_HANDLE;
    VkDeviceSize offset = 0;
    VkDeviceAddress address = 0;
};

// A build waiting in a command buffer: the queue sets `signal`, then waits for `release`.
struct PausedBuild {
    VkEvent signal = VK_NULL_HANDLE;
    VkEvent release = VK_NULL_HANDLE;
    std::unique_ptr<RecordedBuild> build;
};

struct DeviceState {
    VkDevice device = VK_NULL_HANDLE;
    PFN_vkGetDeviceProcAddr next_gdpa = nullptr;
    VkPhysicalDeviceMemoryProperties memory_types{};
#define STANDIN_NEXT(name) PFN_vk##name name = nullptr;
    // An X-macro list, which clang-format re-wraps differently on each run.
    // clang-format off
#define STANDIN_DEVICE_CALLS(X) \
    X(DestroyDevice) X(AllocateMemory) X(FreeMemory) X(MapMemory) X(UnmapMemory) X(CreateBuffer) \
    X(DestroyBuffer) X(BindBufferMemory) X(BindBufferMemory2) X(GetBufferDeviceAddress) \
    X(BeginCommandBuffer) X(QueueSubmit) X(QueueSubmit2) X(CreateEvent) X(DestroyEvent) \
    X(GetEventStatus) X(SetEvent) X(ResetEvent) X(CmdPipelineBarrier) X(CmdSetEvent) \
    X(CmdWaitEvents) X(CmdResetEvent) X(DeviceWaitIdle) X(AllocateCommandBuffers) \
    X(FreeCommandBuffers) X(ResetCommandBuffer) X(ResetCommandPool) X(DestroyCommandPool)
    // clang-format on
    struct Next {
        STANDIN_DEVICE_CALLS(STANDIN_NEXT)
    } next;

    std::mutex mutex;  // memory, buffers, recorded builds
    std::unordered_map<VkDeviceMemory, MemoryState> memories;
    std::unordered_map<VkBuffer, BufferState> buffers;
    std::unordered_map<VkCommandBuffer, std::vector<std::shared_ptr<PausedBuild>>> recorded;
    std::unordered_map<VkCommandBuffer, VkCommandPool> pools;  // for vkResetCommandPool & co
    engine::ObjectDirectory directory;

    std::mutex queue_mutex;  // the builds submitted, in submission order
    std::condition_variable queued;
    std::deque<std::shared_ptr<PausedBuild>> pending;
    bool stopping = false;
    std::thread worker;
};

std::mutex g_mutex;
std::unordered_map<void*, std::unique_ptr<InstanceState>> g_instances;
std::unordered_map<void*, std::unique_ptr<DeviceState>> g_devices;

InstanceState& instance_of(const void* handle) {
    std::lock_guard lock(g_mutex);
    return *g_instances.at(dispatch_key(handle));
}

DeviceState& device_of(const void* handle) {
    std::lock_guard lock(g_mutex);
    return *g_devices.at(dispatch_key(handle));
}

// ---- the builds, run by the device's worker while the queue waits ----

std::vector<HostBuffer> host_buffers(const DeviceState& d) {
    std::vector<HostBuffer> out;
    for (const auto& [buffer, b] : d.buffers) {
        auto memory = d.memories.find(b.memory);
        if (b.address == 0 || memory == d.memories.end() || !memory->second.host) continue;
        out.push_back({b.address, b.size, memory->second.host + b.offset, b.usage});
    }
    return out;
}

void run_paused(DeviceState& d, const PausedBuild& paused) {
    while (d.next.GetEventStatus(d.device, paused.signal) != VK_EVENT_SET) {
        {
            std::lock_guard lock(d.queue_mutex);
            if (d.stopping) return;
        }
        std::this_thread::sleep_for(std::chrono::microseconds(50));
    }
    d.next.ResetEvent(d.device, paused.signal);
    {
        std::lock_guard lock(d.mutex);
        execute_on_host(*paused.build, host_buffers(d), d.directory);
    }
    d.next.SetEvent(d.device, paused.release);
}

void work(DeviceState& d) {
    for (;;) {
        std::shared_ptr<PausedBuild> next;
        {
            std::unique_lock lock(d.queue_mutex);
            d.queued.wait(lock, [&] { return d.stopping || !d.pending.empty(); });
            if (d.stopping) return;
            next = d.pending.front();
            d.pending.pop_front();
        }
        run_paused(d, *next);
    }
}

void expect_builds(DeviceState& d, const VkCommandBuffer* buffers, uint32_t count) {
    std::vector<std::shared_ptr<PausedBuild>> builds;
    {
        std::lock_guard lock(d.mutex);
        for (uint32_t i = 0; i < count; ++i) {
            auto it = d.recorded.find(buffers[i]);
            if (it != d.recorded.end())
                builds.insert(builds.end(), it->second.begin(), it->second.end());
        }
    }
    if (builds.empty()) return;
    std::lock_guard lock(d.queue_mutex);
    d.pending.insert(d.pending.end(), builds.begin(), builds.end());
    d.queued.notify_one();
}

// ---- the extension's entry points ----

VKAPI_ATTR void VKAPI_CALL GetClusterAccelerationStructureBuildSizesNV(
    VkDevice, const VkClusterAccelerationStructureInputInfoNV* info,
    VkAccelerationStructureBuildSizesInfoKHR* sizes) {
    const StandinSizes answer = standin_build_sizes(*info);
    sizes->accelerationStructureSize = answer.acceleration_structure_size;
    sizes->buildScratchSize = answer.build_scratch_size;
    sizes->updateScratchSize = 0;
}

VKAPI_ATTR void VKAPI_CALL CmdBuildClusterAccelerationStructureIndirectNV(
    VkCommandBuffer cb, const VkClusterAccelerationStructureCommandsInfoNV* info) {
    DeviceState& d = device_of(cb);
    auto paused = std::make_shared<PausedBuild>();
    const VkEventCreateInfo event_info{VK_STRUCTURE_TYPE_EVENT_CREATE_INFO, nullptr, 0};
    d.next.CreateEvent(d.device, &event_info, nullptr, &paused->signal);
    d.next.CreateEvent(d.device, &event_info, nullptr, &paused->release);
    paused->build = std::make_unique<RecordedBuild>(*info);
    // Everything before is done and visible to the host when `signal` is set; what the host
    // wrote is visible to everything after once `release` is.
    VkMemoryBarrier before{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr, VK_ACCESS_MEMORY_WRITE_BIT,
                           VK_ACCESS_HOST_READ_BIT | VK_ACCESS_MEMORY_READ_BIT};
    d.next.CmdPipelineBarrier(cb, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT,
                              VK_PIPELINE_STAGE_ALL_COMMANDS_BIT | VK_PIPELINE_STAGE_HOST_BIT, 0, 1,
                              &before, 0, nullptr, 0, nullptr);
    d.next.CmdSetEvent(cb, paused->signal, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT);
    VkMemoryBarrier after{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr, VK_ACCESS_HOST_WRITE_BIT,
                          VK_ACCESS_MEMORY_READ_BIT | VK_ACCESS_MEMORY_WRITE_BIT};
    d.next.CmdWaitEvents(cb, 1, &paused->release, VK_PIPELINE_STAGE_HOST_BIT,
                         VK_PIPELINE_STAGE_ALL_COMMANDS_BIT, 1, &after, 0, nullptr, 0, nullptr);
    d.next.CmdResetEvent(cb, paused->release, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT);
    std::lock_guard lock(d.mutex);
    d.recorded[cb].push_back(std::move(paused));
}

// ---- device calls the stand-in watches ----

void destroy_events(DeviceState& d, const std::vector<std::shared_ptr<PausedBuild>>& builds) {
    for (const auto& b : builds) {
        d.next.DestroyEvent(d.device, b->signal, nullptr);
        d.next.DestroyEvent(d.device, b->release, nullptr);
    }
}

// The pauses recorded in `cb`, which is being begun, reset or freed (so not pending), go.
// Takes d.mutex.
void forget_recorded(DeviceState& d, VkCommandBuffer cb) {
    auto it = d.recorded.find(cb);
    if (it == d.recorded.end()) return;
    destroy_events(d, it->second);
    d.recorded.erase(it);
}

VKAPI_ATTR VkResult VKAPI_CALL BeginCommandBuffer(VkCommandBuffer cb,
                                                  const VkCommandBufferBeginInfo* info) {
    DeviceState& d = device_of(cb);
    {
        std::lock_guard lock(d.mutex);
        forget_recorded(d, cb);
    }
    return d.next.BeginCommandBuffer(cb, info);
}

VKAPI_ATTR VkResult VKAPI_CALL ResetCommandBuffer(VkCommandBuffer cb,
                                                  VkCommandBufferResetFlags flags) {
    DeviceState& d = device_of(cb);
    {
        std::lock_guard lock(d.mutex);
        forget_recorded(d, cb);
    }
    return d.next.ResetCommandBuffer(cb, flags);
}

VKAPI_ATTR VkResult VKAPI_CALL AllocateCommandBuffers(VkDevice device,
                                                      const VkCommandBufferAllocateInfo* info,
                                                      VkCommandBuffer* buffers) {
    DeviceState& d = device_of(device);
    const VkResult result = d.next.AllocateCommandBuffers(device, info, buffers);
    if (result != VK_SUCCESS) return result;
    std::lock_guard lock(d.mutex);
    for (uint32_t i = 0; i < info->commandBufferCount; ++i) d.pools[buffers[i]] = info->commandPool;
    return result;
}

VKAPI_ATTR void VKAPI_CALL FreeCommandBuffers(VkDevice device, VkCommandPool pool, uint32_t count,
                                              const VkCommandBuffer* buffers) {
    DeviceState& d = device_of(device);
    {
        std::lock_guard lock(d.mutex);
        for (uint32_t i = 0; i < count; ++i) {
            if (!buffers[i]) continue;
            forget_recorded(d, buffers[i]);
            d.pools.erase(buffers[i]);
        }
    }
    d.next.FreeCommandBuffers(device, pool, count, buffers);
}

// Every command buffer of `pool` forgets its pauses; `freed`: and is forgotten itself.
void forget_pool(DeviceState& d, VkCommandPool pool, bool freed) {
    std::lock_guard lock(d.mutex);
    for (auto it = d.pools.begin(); it != d.pools.end();) {
        if (it->second != pool) {
            ++it;
            continue;
        }
        forget_recorded(d, it->first);
        it = freed ? d.pools.erase(it) : std::next(it);
    }
}

VKAPI_ATTR VkResult VKAPI_CALL ResetCommandPool(VkDevice device, VkCommandPool pool,
                                                VkCommandPoolResetFlags flags) {
    DeviceState& d = device_of(device);
    forget_pool(d, pool, false);
    return d.next.ResetCommandPool(device, pool, flags);
}

VKAPI_ATTR void VKAPI_CALL DestroyCommandPool(VkDevice device, VkCommandPool pool,
                                              const VkAllocationCallbacks* allocator) {
    DeviceState& d = device_of(device);
    forget_pool(d, pool, true);
    d.next.DestroyCommandPool(device, pool, allocator);
}

VKAPI_ATTR VkResult VKAPI_CALL QueueSubmit(VkQueue queue, uint32_t count,
                                           const VkSubmitInfo* submits, VkFence fence) {
    DeviceState& d = device_of(queue);
    const VkResult result = d.next.QueueSubmit(queue, count, submits, fence);
    if (result == VK_SUCCESS)
        for (uint32_t s = 0; s < count; ++s)
            expect_builds(d, submits[s].pCommandBuffers, submits[s].commandBufferCount);
    return result;
}

VKAPI_ATTR VkResult VKAPI_CALL QueueSubmit2(VkQueue queue, uint32_t count,
                                            const VkSubmitInfo2* submits, VkFence fence) {
    DeviceState& d = device_of(queue);
    const VkResult result = d.next.QueueSubmit2(queue, count, submits, fence);
    if (result != VK_SUCCESS) return result;
    for (uint32_t s = 0; s < count; ++s) {
        std::vector<VkCommandBuffer> buffers;
        for (uint32_t i = 0; i < submits[s].commandBufferInfoCount; ++i)
            buffers.push_back(submits[s].pCommandBufferInfos[i].commandBuffer);
        expect_builds(d, buffers.data(), static_cast<uint32_t>(buffers.size()));
    }
    return result;
}

VKAPI_ATTR VkResult VKAPI_CALL AllocateMemory(VkDevice device, const VkMemoryAllocateInfo* info,
                                              const VkAllocationCallbacks* allocator,
                                              VkDeviceMemory* memory) {
    DeviceState& d = device_of(device);
    VkResult result = d.next.AllocateMemory(device, info, allocator, memory);
    if (result != VK_SUCCESS) return result;
    MemoryState state;
    const VkMemoryPropertyFlags flags =
        d.memory_types.memoryTypes[info->memoryTypeIndex].propertyFlags;
    if (flags & VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT) {
        void* host = nullptr;
        if (d.next.MapMemory(device, *memory, 0, VK_WHOLE_SIZE, 0, &host) == VK_SUCCESS)
            state.host = static_cast<uint8_t*>(host);
    }
    std::lock_guard lock(d.mutex);
    d.memories[*memory] = state;
    return result;
}

VKAPI_ATTR void VKAPI_CALL FreeMemory(VkDevice device, VkDeviceMemory memory,
                                      const VkAllocationCallbacks* allocator) {
    DeviceState& d = device_of(device);
    {
        std::lock_guard lock(d.mutex);
        auto it = d.memories.find(memory);
        if (it != d.memories.end() && it->second.host) d.next.UnmapMemory(device, memory);
        d.memories.erase(memory);
    }
    d.next.FreeMemory(device, memory, allocator);
}

// The application maps what the stand-in already holds mapped.
VKAPI_ATTR VkResult VKAPI_CALL MapMemory(VkDevice device, VkDeviceMemory memory,
                                         VkDeviceSize offset, VkDeviceSize, VkMemoryMapFlags,
                                         void** data) {
    DeviceState& d = device_of(device);
    std::lock_guard lock(d.mutex);
    auto it = d.memories.find(memory);
    if (it == d.memories.end() || !it->second.host) return VK_ERROR_MEMORY_MAP_FAILED;
    *data = it->second.host + offset;
    return VK_SUCCESS;
}

VKAPI_ATTR void VKAPI_CALL UnmapMemory(VkDevice, VkDeviceMemory) {}

VKAPI_ATTR VkResult VKAPI_CALL CreateBuffer(VkDevice device, const VkBufferCreateInfo* info,
                                            const VkAllocationCallbacks* allocator,
                                            VkBuffer* buffer) {
    DeviceState& d = device_of(device);
    VkResult result = d.next.CreateBuffer(device, info, allocator, buffer);
    if (result != VK_SUCCESS) return result;
    std::lock_guard lock(d.mutex);
    d.buffers[*buffer] = {info->size, info->usage};
    return result;
}

VKAPI_ATTR void VKAPI_CALL DestroyBuffer(VkDevice device, VkBuffer buffer,
                                         const VkAllocationCallbacks* allocator) {
    DeviceState& d = device_of(device);
    {
        std::lock_guard lock(d.mutex);
        auto it = d.buffers.find(buffer);
        if (it != d.buffers.end() && it->second.address)
            d.directory.forget(it->second.address, it->second.address + it->second.size);
        d.buffers.erase(buffer);
    }
    d.next.DestroyBuffer(device, buffer, allocator);
}

void remember_binding(DeviceState& d, VkBuffer buffer, VkDeviceMemory memory, VkDeviceSize offset) {
    std::lock_guard lock(d.mutex);
    auto it = d.buffers.find(buffer);
    if (it == d.buffers.end()) return;
    it->second.memory = memory;
    it->second.offset = offset;
}

VKAPI_ATTR VkResult VKAPI_CALL BindBufferMemory(VkDevice device, VkBuffer buffer,
                                                VkDeviceMemory memory, VkDeviceSize offset) {
    DeviceState& d = device_of(device);
    VkResult result = d.next.BindBufferMemory(device, buffer, memory, offset);
    if (result == VK_SUCCESS) remember_binding(d, buffer, memory, offset);
    return result;
}

VKAPI_ATTR VkResult VKAPI_CALL BindBufferMemory2(VkDevice device, uint32_t count,
                                                 const VkBindBufferMemoryInfo* infos) {
    DeviceState& d = device_of(device);
    VkResult result = d.next.BindBufferMemory2(device, count, infos);
    if (result == VK_SUCCESS)
        for (uint32_t i = 0; i < count; ++i)
            remember_binding(d, infos[i].buffer, infos[i].memory, infos[i].memoryOffset);
    return result;
}

VKAPI_ATTR VkDeviceAddress VKAPI_CALL
GetBufferDeviceAddress(VkDevice device, const VkBufferDeviceAddressInfo* info) {
    DeviceState& d = device_of(device);
    const VkDeviceAddress address = d.next.GetBufferDeviceAddress(device, info);
    std::lock_guard lock(d.mutex);
    auto it = d.buffers.find(info->buffer);
    if (it != d.buffers.end()) it->second.address = address;
    return address;
}

VKAPI_ATTR void VKAPI_CALL DestroyDevice(VkDevice device, const VkAllocationCallbacks* allocator) {
    std::unique_ptr<DeviceState> d;
    {
        std::lock_guard lock(g_mutex);
        auto it = g_devices.find(dispatch_key(device));
        if (it == g_devices.end()) return;
        d = std::move(it->second);
        g_devices.erase(it);
    }
    {
        std::lock_guard lock(d->queue_mutex);
        d->stopping = true;
        d->queued.notify_one();
    }
    d->worker.join();
    for (const auto& [cb, builds] : d->recorded) destroy_events(*d, builds);
    for (const auto& [memory, state] : d->memories)
        if (state.host) d->next.UnmapMemory(device, memory);
    d->next.DestroyDevice(device, allocator);
}

PFN_vkVoidFunction device_call(const char* name);

VKAPI_ATTR PFN_vkVoidFunction VKAPI_CALL GetDeviceProcAddr(VkDevice device, const char* name) {
    if (PFN_vkVoidFunction own = device_call(name)) return own;
    return device_of(device).next_gdpa(device, name);
}

PFN_vkVoidFunction device_call(const char* name) {
    static const std::map<std::string, PFN_vkVoidFunction> calls = {
        {"vkGetDeviceProcAddr", reinterpret_cast<PFN_vkVoidFunction>(GetDeviceProcAddr)},
        {"vkDestroyDevice", reinterpret_cast<PFN_vkVoidFunction>(DestroyDevice)},
        {"vkGetClusterAccelerationStructureBuildSizesNV",
         reinterpret_cast<PFN_vkVoidFunction>(GetClusterAccelerationStructureBuildSizesNV)},
        {"vkCmdBuildClusterAccelerationStructureIndirectNV",
         reinterpret_cast<PFN_vkVoidFunction>(CmdBuildClusterAccelerationStructureIndirectNV)},
        {"vkBeginCommandBuffer", reinterpret_cast<PFN_vkVoidFunction>(BeginCommandBuffer)},
        {"vkResetCommandBuffer", reinterpret_cast<PFN_vkVoidFunction>(ResetCommandBuffer)},
        {"vkAllocateCommandBuffers", reinterpret_cast<PFN_vkVoidFunction>(AllocateCommandBuffers)},
        {"vkFreeCommandBuffers", reinterpret_cast<PFN_vkVoidFunction>(FreeCommandBuffers)},
        {"vkResetCommandPool", reinterpret_cast<PFN_vkVoidFunction>(ResetCommandPool)},
        {"vkDestroyCommandPool", reinterpret_cast<PFN_vkVoidFunction>(DestroyCommandPool)},
        {"vkQueueSubmit", reinterpret_cast<PFN_vkVoidFunction>(QueueSubmit)},
        {"vkQueueSubmit2", reinterpret_cast<PFN_vkVoidFunction>(QueueSubmit2)},
        {"vkQueueSubmit2KHR", reinterpret_cast<PFN_vkVoidFunction>(QueueSubmit2)},
        {"vkAllocateMemory", reinterpret_cast<PFN_vkVoidFunction>(AllocateMemory)},
        {"vkFreeMemory", reinterpret_cast<PFN_vkVoidFunction>(FreeMemory)},
        {"vkMapMemory", reinterpret_cast<PFN_vkVoidFunction>(MapMemory)},
        {"vkUnmapMemory", reinterpret_cast<PFN_vkVoidFunction>(UnmapMemory)},
        {"vkCreateBuffer", reinterpret_cast<PFN_vkVoidFunction>(CreateBuffer)},
        {"vkDestroyBuffer", reinterpret_cast<PFN_vkVoidFunction>(DestroyBuffer)},
        {"vkBindBufferMemory", reinterpret_cast<PFN_vkVoidFunction>(BindBufferMemory)},
        {"vkBindBufferMemory2", reinterpret_cast<PFN_vkVoidFunction>(BindBufferMemory2)},
        {"vkBindBufferMemory2KHR", reinterpret_cast<PFN_vkVoidFunction>(BindBufferMemory2)},
        {"vkGetBufferDeviceAddress", reinterpret_cast<PFN_vkVoidFunction>(GetBufferDeviceAddress)},
        {"vkGetBufferDeviceAddressKHR",
         reinterpret_cast<PFN_vkVoidFunction>(GetBufferDeviceAddress)},
        {"vkGetBufferDeviceAddressEXT",
         reinterpret_cast<PFN_vkVoidFunction>(GetBufferDeviceAddress)},
    };
    auto it = calls.find(name);
    return it == calls.end() ? nullptr : it->second;
}

// ---- instance calls: the extension as the physical device's own ----

VkExtensionProperties cluster_extension() {
    VkExtensionProperties e{};
    std::strncpy(e.extensionName, VK_NV_CLUSTER_ACCELERATION_STRUCTURE_EXTENSION_NAME,
                 VK_MAX_EXTENSION_NAME_SIZE - 1);
    e.specVersion = VK_NV_CLUSTER_ACCELERATION_STRUCTURE_SPEC_VERSION;
    return e;
}

VkResult copy_out(const std::vector<VkExtensionProperties>& list, uint32_t* count,
                  VkExtensionProperties* out) {
    if (!out) {
        *count = static_cast<uint32_t>(list.size());
        return VK_SUCCESS;
    }
    const uint32_t n = std::min<uint32_t>(*count, static_cast<uint32_t>(list.size()));
    std::copy(list.begin(), list.begin() + n, out);
    *count = n;
    return n < list.size() ? VK_INCOMPLETE : VK_SUCCESS;
}

VKAPI_ATTR VkResult VKAPI_CALL EnumerateDeviceExtensionProperties(VkPhysicalDevice gpu,
                                                                  const char* layer,
                                                                  uint32_t* count,
                                                                  VkExtensionProperties* out) {
    if (layer && std::strcmp(layer, kLayerName) == 0)
        return copy_out({cluster_extension()}, count, out);
    InstanceState& s = instance_of(gpu);
    auto next = s.enumerate_device_extensions;
    if (layer) return next(gpu, layer, count, out);
    uint32_t below = 0;
    VkResult result = next(gpu, nullptr, &below, nullptr);
    if (result != VK_SUCCESS) return result;
    std::vector<VkExtensionProperties> list(below);
    result = next(gpu, nullptr, &below, list.data());
    if (result != VK_SUCCESS) return result;
    list.resize(below);
    list.push_back(cluster_extension());
    return copy_out(list, count, out);
}

template <class T>
T* find_in_chain(void* chain, VkStructureType type) {
    for (auto* n = static_cast<VkBaseOutStructure*>(chain); n; n = n->pNext)
        if (n->sType == type) return reinterpret_cast<T*>(n);
    return nullptr;
}

VKAPI_ATTR void VKAPI_CALL GetPhysicalDeviceFeatures2(VkPhysicalDevice gpu,
                                                      VkPhysicalDeviceFeatures2* features) {
    instance_of(gpu).get_features2(gpu, features);
    if (auto* cluster = find_in_chain<VkPhysicalDeviceClusterAccelerationStructureFeaturesNV>(
            features->pNext,
            VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_CLUSTER_ACCELERATION_STRUCTURE_FEATURES_NV))
        cluster->clusterAccelerationStructure = VK_TRUE;
}

VKAPI_ATTR void VKAPI_CALL GetPhysicalDeviceProperties2(VkPhysicalDevice gpu,
                                                        VkPhysicalDeviceProperties2* properties) {
    instance_of(gpu).get_properties2(gpu, properties);
    if (auto* cluster = find_in_chain<VkPhysicalDeviceClusterAccelerationStructurePropertiesNV>(
            properties->pNext,
            VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_CLUSTER_ACCELERATION_STRUCTURE_PROPERTIES_NV)) {
        void* chain = cluster->pNext;
        *cluster = engine::EngineProperties::nvidia_default().to_vk();
        cluster->sType =
            VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_CLUSTER_ACCELERATION_STRUCTURE_PROPERTIES_NV;
        cluster->pNext = chain;
    }
}

template <class Info>
VkLayerInstanceCreateInfo* instance_link(const Info* info) {
    for (auto* n = static_cast<const VkBaseInStructure*>(info->pNext); n; n = n->pNext) {
        auto* link =
            reinterpret_cast<VkLayerInstanceCreateInfo*>(const_cast<VkBaseInStructure*>(n));
        if (n->sType == VK_STRUCTURE_TYPE_LOADER_INSTANCE_CREATE_INFO &&
            link->function == VK_LAYER_LINK_INFO)
            return link;
    }
    return nullptr;
}

VkLayerDeviceCreateInfo* device_link(const VkDeviceCreateInfo* info) {
    for (auto* n = static_cast<const VkBaseInStructure*>(info->pNext); n; n = n->pNext) {
        auto* link = reinterpret_cast<VkLayerDeviceCreateInfo*>(const_cast<VkBaseInStructure*>(n));
        if (n->sType == VK_STRUCTURE_TYPE_LOADER_DEVICE_CREATE_INFO &&
            link->function == VK_LAYER_LINK_INFO)
            return link;
    }
    return nullptr;
}

VKAPI_ATTR VkResult VKAPI_CALL CreateInstance(const VkInstanceCreateInfo* info,
                                              const VkAllocationCallbacks* allocator,
                                              VkInstance* instance) {
    VkLayerInstanceCreateInfo* link = instance_link(info);
    if (!link) return VK_ERROR_INITIALIZATION_FAILED;
    PFN_vkGetInstanceProcAddr next_gipa = link->u.pLayerInfo->pfnNextGetInstanceProcAddr;
    link->u.pLayerInfo = link->u.pLayerInfo->pNext;
    auto create =
        reinterpret_cast<PFN_vkCreateInstance>(next_gipa(VK_NULL_HANDLE, "vkCreateInstance"));
    VkResult result = create(info, allocator, instance);
    if (result != VK_SUCCESS) return result;
    auto state = std::make_unique<InstanceState>();
    state->next_gipa = next_gipa;
    state->instance = *instance;
    const auto resolve = [&](const char* name) { return next_gipa(*instance, name); };
    state->enumerate_device_extensions = reinterpret_cast<PFN_vkEnumerateDeviceExtensionProperties>(
        resolve("vkEnumerateDeviceExtensionProperties"));
    state->get_features2 =
        reinterpret_cast<PFN_vkGetPhysicalDeviceFeatures2>(resolve("vkGetPhysicalDeviceFeatures2"));
    state->get_properties2 = reinterpret_cast<PFN_vkGetPhysicalDeviceProperties2>(
        resolve("vkGetPhysicalDeviceProperties2"));
    state->get_memory_properties = reinterpret_cast<PFN_vkGetPhysicalDeviceMemoryProperties>(
        resolve("vkGetPhysicalDeviceMemoryProperties"));
    state->destroy_instance = reinterpret_cast<PFN_vkDestroyInstance>(resolve("vkDestroyInstance"));
    std::lock_guard lock(g_mutex);
    g_instances[dispatch_key(*instance)] = std::move(state);
    return result;
}

VKAPI_ATTR void VKAPI_CALL DestroyInstance(VkInstance instance,
                                           const VkAllocationCallbacks* allocator) {
    std::unique_ptr<InstanceState> s;
    {
        std::lock_guard lock(g_mutex);
        auto it = g_instances.find(dispatch_key(instance));
        if (it == g_instances.end()) return;
        s = std::move(it->second);
        g_instances.erase(it);
    }
    s->destroy_instance(instance, allocator);
}

// The driver below lacks the extension: its name and feature struct go no further down.
// (The struct is unlinked from the application's chain for the call and linked back after.)
struct HiddenExtension {
    std::vector<const char*> names;
    VkBaseOutStructure* before_feature = nullptr;
    VkBaseOutStructure* feature = nullptr;
    const void* original_first = nullptr;
};

HiddenExtension hide_extension(VkDeviceCreateInfo& info) {
    HiddenExtension hidden;
    for (uint32_t i = 0; i < info.enabledExtensionCount; ++i)
        if (std::strcmp(info.ppEnabledExtensionNames[i],
                        VK_NV_CLUSTER_ACCELERATION_STRUCTURE_EXTENSION_NAME) != 0)
            hidden.names.push_back(info.ppEnabledExtensionNames[i]);
    info.enabledExtensionCount = static_cast<uint32_t>(hidden.names.size());
    info.ppEnabledExtensionNames = hidden.names.data();
    hidden.original_first = info.pNext;
    VkBaseOutStructure* previous = nullptr;
    for (auto* n = static_cast<VkBaseOutStructure*>(const_cast<void*>(info.pNext)); n;
         previous = n, n = n->pNext) {
        if (n->sType !=
            VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_CLUSTER_ACCELERATION_STRUCTURE_FEATURES_NV)
            continue;
        hidden.feature = n;
        hidden.before_feature = previous;
        if (previous)
            previous->pNext = n->pNext;
        else
            info.pNext = n->pNext;
        break;
    }
    return hidden;
}

void restore_chain(const HiddenExtension& hidden) {
    if (hidden.before_feature) hidden.before_feature->pNext = hidden.feature;
}

VKAPI_ATTR VkResult VKAPI_CALL CreateDevice(VkPhysicalDevice gpu, const VkDeviceCreateInfo* info,
                                            const VkAllocationCallbacks* allocator,
                                            VkDevice* device) {
    VkLayerDeviceCreateInfo* link = device_link(info);
    if (!link) return VK_ERROR_INITIALIZATION_FAILED;
    PFN_vkGetInstanceProcAddr next_gipa = link->u.pLayerInfo->pfnNextGetInstanceProcAddr;
    PFN_vkGetDeviceProcAddr next_gdpa = link->u.pLayerInfo->pfnNextGetDeviceProcAddr;
    link->u.pLayerInfo = link->u.pLayerInfo->pNext;
    InstanceState& s = instance_of(gpu);
    auto create = reinterpret_cast<PFN_vkCreateDevice>(next_gipa(s.instance, "vkCreateDevice"));
    VkDeviceCreateInfo below = *info;
    const HiddenExtension hidden = hide_extension(below);
    VkResult result = create(gpu, &below, allocator, device);
    restore_chain(hidden);
    if (result != VK_SUCCESS) return result;

    auto d = std::make_unique<DeviceState>();
    d->device = *device;
    d->next_gdpa = next_gdpa;
    s.get_memory_properties(gpu, &d->memory_types);
#define STANDIN_RESOLVE(name) \
    d->next.name = reinterpret_cast<PFN_vk##name>(next_gdpa(*device, "vk" #name));
    STANDIN_DEVICE_CALLS(STANDIN_RESOLVE)
    DeviceState* raw = d.get();
    d->worker = std::thread([raw] { work(*raw); });
    std::lock_guard lock(g_mutex);
    g_devices[dispatch_key(*device)] = std::move(d);
    return result;
}

PFN_vkVoidFunction instance_call(const char* name) {
    static const std::map<std::string, PFN_vkVoidFunction> calls = {
        {"vkCreateInstance", reinterpret_cast<PFN_vkVoidFunction>(CreateInstance)},
        {"vkDestroyInstance", reinterpret_cast<PFN_vkVoidFunction>(DestroyInstance)},
        {"vkCreateDevice", reinterpret_cast<PFN_vkVoidFunction>(CreateDevice)},
        {"vkEnumerateDeviceExtensionProperties",
         reinterpret_cast<PFN_vkVoidFunction>(EnumerateDeviceExtensionProperties)},
        {"vkGetPhysicalDeviceFeatures2",
         reinterpret_cast<PFN_vkVoidFunction>(GetPhysicalDeviceFeatures2)},
        {"vkGetPhysicalDeviceFeatures2KHR",
         reinterpret_cast<PFN_vkVoidFunction>(GetPhysicalDeviceFeatures2)},
        {"vkGetPhysicalDeviceProperties2",
         reinterpret_cast<PFN_vkVoidFunction>(GetPhysicalDeviceProperties2)},
        {"vkGetPhysicalDeviceProperties2KHR",
         reinterpret_cast<PFN_vkVoidFunction>(GetPhysicalDeviceProperties2)},
    };
    auto it = calls.find(name);
    return it == calls.end() ? nullptr : it->second;
}

}  // namespace
}  // namespace clastrace::standin

using namespace clastrace::standin;

extern "C" {

__attribute__((visibility("default"))) VKAPI_ATTR PFN_vkVoidFunction VKAPI_CALL
clastrace_standin_GetInstanceProcAddr(VkInstance instance, const char* name) {
    if (PFN_vkVoidFunction own = instance_call(name)) return own;
    if (PFN_vkVoidFunction own = device_call(name)) return own;
    if (!instance) return nullptr;
    return instance_of(instance).next_gipa(instance, name);
}

__attribute__((visibility("default"))) VKAPI_ATTR PFN_vkVoidFunction VKAPI_CALL
clastrace_standin_GetDeviceProcAddr(VkDevice device, const char* name) {
    return GetDeviceProcAddr(device, name);
}

// For tests (found with dlsym): the pause events the stand-in holds over all devices.
__attribute__((visibility("default"))) size_t clastrace_standin_live_pause_events() {
    std::lock_guard lock(g_mutex);
    size_t events = 0;
    for (const auto& [key, d] : g_devices) {
        std::lock_guard device_lock(d->mutex);
        for (const auto& [cb, builds] : d->recorded) events += 2 * builds.size();
    }
    return events;
}

__attribute__((visibility("default"))) VKAPI_ATTR VkResult VKAPI_CALL
vkNegotiateLoaderLayerInterfaceVersion(VkNegotiateLayerInterface* interface) {
    if (interface->loaderLayerInterfaceVersion < 2) return VK_ERROR_INITIALIZATION_FAILED;
    interface->loaderLayerInterfaceVersion = 2;
    interface->pfnGetInstanceProcAddr = clastrace_standin_GetInstanceProcAddr;
    interface->pfnGetDeviceProcAddr = clastrace_standin_GetDeviceProcAddr;
    interface->pfnGetPhysicalDeviceProcAddr = nullptr;
    return VK_SUCCESS;
}

}  // extern "C"
