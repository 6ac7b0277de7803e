// SPDX-License-Identifier: Apache-2.0
// Loader-facing part: interface negotiation, instance and device creation with the next
// layer's entry points, the registries, and the proc-address interception.
#include "layer_state.h"

#include "clastrace/capture/background_cpus.h"
#include "clastrace/capture/capture_cost.h"
#include "command_buffer_log.h"
#include "pause_worker.h"

#include <algorithm>
#include <atomic>
#include <cstdio>
#include <cstring>
#include <string>

namespace clastrace::capture {
namespace {

constexpr const char* kLayerName = "VK_LAYER_CLASTRACE_capture";

std::shared_mutex registryMutex;
std::unordered_map<DispatchKey, std::unique_ptr<InstanceState>>& instances() {
    static std::unordered_map<DispatchKey, std::unique_ptr<InstanceState>> map;
    return map;
}
std::unordered_map<DispatchKey, std::unique_ptr<DeviceState>>& devices() {
    static std::unordered_map<DispatchKey, std::unique_ptr<DeviceState>> map;
    return map;
}

template <typename CreateInfo, typename LinkInfo>
LinkInfo* find_layer_link(const CreateInfo* create_info, VkStructureType type) {
    auto* link = (LinkInfo*)create_info->pNext;
    while (link && !(link->sType == type && link->function == VK_LAYER_LINK_INFO))
        link = (LinkInfo*)link->pNext;
    return link;
}

VKAPI_ATTR VkResult VKAPI_CALL CreateInstance(const VkInstanceCreateInfo* p_create_info,
                                              const VkAllocationCallbacks* p_allocator,
                                              VkInstance* pInstance) {
    auto* link = find_layer_link<VkInstanceCreateInfo, VkLayerInstanceCreateInfo>(
        p_create_info, VK_STRUCTURE_TYPE_LOADER_INSTANCE_CREATE_INFO);
    if (!link || !link->u.pLayerInfo) return VK_ERROR_INITIALIZATION_FAILED;
    PFN_vkGetInstanceProcAddr nextGipa = link->u.pLayerInfo->pfnNextGetInstanceProcAddr;
    auto next_create = (PFN_vkCreateInstance)nextGipa(VK_NULL_HANDLE, "vkCreateInstance");
    if (!next_create) return VK_ERROR_INITIALIZATION_FAILED;
    link->u.pLayerInfo = link->u.pLayerInfo->pNext;  // the next layer finds its own link
    VkResult result = next_create(p_create_info, p_allocator, pInstance);
    if (result != VK_SUCCESS) return result;

    layer_config();  // parse (and report) the settings at a predictable moment
    auto state = std::make_unique<InstanceState>();
    state->instance = *pInstance;
    if (const VkApplicationInfo* app = p_create_info->pApplicationInfo) {
        if (app->pApplicationName) state->application_name = app->pApplicationName;
        if (app->pEngineName) state->engine_name = app->pEngineName;
    }
    state->api_version =
        p_create_info->pApplicationInfo && p_create_info->pApplicationInfo->apiVersion
            ? p_create_info->pApplicationInfo->apiVersion
            : VK_API_VERSION_1_0;
#define CLASTRACE_LOAD(name) state->next.name = (PFN_vk##name)nextGipa(*pInstance, "vk" #name);
    CLASTRACE_INSTANCE_FUNCTIONS(CLASTRACE_LOAD)
#undef CLASTRACE_LOAD
    state->next.GetInstanceProcAddr = nextGipa;
    register_instance(dispatch_key(*pInstance), std::move(state));
    return VK_SUCCESS;
}

VKAPI_ATTR void VKAPI_CALL DestroyInstance(VkInstance instance,
                                           const VkAllocationCallbacks* p_allocator) {
    auto state = unregister_instance(dispatch_key(instance));
    if (state && state->next.DestroyInstance) state->next.DestroyInstance(instance, p_allocator);
}

// Driver name, UUIDs and NV ray-tracing limits (Vulkan 1.2 devices): what tells a serialized
// acceleration structure of this driver from another's, and what the ray check builds on.
void fill_driver_identity(InstanceState& instance, VkPhysicalDevice physical_device,
                          uint32_t api_version, DeviceState& state, DeviceRecord& record) {
    if (!instance.next.GetPhysicalDeviceProperties2 || api_version < VK_API_VERSION_1_2) return;
    VkPhysicalDeviceRayTracingPropertiesNV ray_tracing{};
    ray_tracing.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_RAY_TRACING_PROPERTIES_NV;
    VkPhysicalDeviceDriverProperties driver{};
    driver.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_DRIVER_PROPERTIES;
    driver.pNext = state.nv_ray_tracing_enabled ? &ray_tracing : nullptr;
    VkPhysicalDeviceIDProperties ids{};
    ids.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_ID_PROPERTIES;
    ids.pNext = &driver;
    VkPhysicalDeviceProperties2 properties{};
    properties.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2;
    properties.pNext = &ids;
    instance.next.GetPhysicalDeviceProperties2(physical_device, &properties);
    record.driver_id = uint32_t(driver.driverID);
    record.driver_name = driver.driverName;
    record.driver_info = driver.driverInfo;
    record.driver_uuid.assign(ids.driverUUID, ids.driverUUID + VK_UUID_SIZE);
    record.device_uuid.assign(ids.deviceUUID, ids.deviceUUID + VK_UUID_SIZE);
    if (state.nv_ray_tracing_enabled) {
        ray_tracing.pNext = nullptr;
        state.ray_tracing_properties_nv = ray_tracing;
        record.has_ray_tracing_properties_nv = true;
        record.ray_tracing_properties_nv = ray_tracing;
    }
}

// Why the KHR ray check is off, said once per process at info level (an application may create
// many devices).
enum RayCheckOffReason { kRayCheckNoKhrStructures, kRayCheckRayQueryOff, kRayCheckNoRayQuery };
void log_once(RayCheckOffReason reason, const char* message) {
    static std::atomic<uint32_t> said{0};
    const uint32_t bit = 1u << reason;
    if (said.fetch_or(bit) & bit) return;
    log_message(LogLevel::kInfo, "%s", message);
}

// CLASTRACE_RAY_CHECK traces KHR top levels with a ray-query compute shader: where the
// application did not enable VK_KHR_ray_query with rayQuery and the device lists it, the layer
// enables both on the driver's device (`feature` heads driver_info's chain; it must outlive the
// vkCreateDevice). True when the device will have rayQuery.
bool enable_ray_query_for_check(InstanceState& instance, VkPhysicalDevice physical_device,
                                std::vector<const char*>& extensions,
                                VkDeviceCreateInfo& driver_info,
                                VkPhysicalDeviceRayQueryFeaturesKHR& feature) {
    bool extension = false, acceleration_structure = false;
    for (const char* name : extensions) {
        extension = extension || std::strcmp(name, VK_KHR_RAY_QUERY_EXTENSION_NAME) == 0;
        acceleration_structure =
            acceleration_structure ||
            std::strcmp(name, VK_KHR_ACCELERATION_STRUCTURE_EXTENSION_NAME) == 0;
    }
    const VkPhysicalDeviceRayQueryFeaturesKHR* asked = nullptr;
    for (auto* s = (const VkBaseInStructure*)driver_info.pNext; s; s = s->pNext)
        if (s->sType == VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_RAY_QUERY_FEATURES_KHR)
            asked = (const VkPhysicalDeviceRayQueryFeaturesKHR*)s;
    if (extension && asked && asked->rayQuery) return true;  // the application's own
    if (layer_config().ray_check_rays == 0) return false;
    // Without VK_KHR_acceleration_structure there are no KHR top levels to check.
    if (!acceleration_structure) {
        log_once(kRayCheckNoKhrStructures,
                 "ray check: the application did not enable VK_KHR_acceleration_structure, so "
                 "there are no KHR top levels to check; NV top levels are checked where the "
                 "application enabled VK_NV_ray_tracing");
        return false;
    }
    if (asked) {
        log_once(kRayCheckRayQueryOff,
                 "ray check: the application chained VkPhysicalDeviceRayQueryFeaturesKHR with "
                 "rayQuery off, which the layer leaves as asked; KHR top levels will not be "
                 "checked (the check traces them with ray queries)");
        return false;
    }
    if (!driver_lists_extension(instance, physical_device, VK_KHR_RAY_QUERY_EXTENSION_NAME)) {
        log_once(kRayCheckNoRayQuery,
                 "ray check: the application enabled VK_KHR_acceleration_structure, but the "
                 "driver does not list VK_KHR_ray_query, which the check needs to trace KHR top "
                 "levels: they will not be checked (NV top levels still are, where the "
                 "application enabled VK_NV_ray_tracing)");
        return false;
    }
    if (!extension) extensions.push_back(VK_KHR_RAY_QUERY_EXTENSION_NAME);
    driver_info.enabledExtensionCount = uint32_t(extensions.size());
    driver_info.ppEnabledExtensionNames = extensions.data();
    feature = VkPhysicalDeviceRayQueryFeaturesKHR{};
    feature.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_RAY_QUERY_FEATURES_KHR;
    feature.rayQuery = VK_TRUE;
    feature.pNext = const_cast<void*>(driver_info.pNext);
    driver_info.pNext = &feature;
    log_message(LogLevel::kInfo,
                "ray check: the layer enables VK_KHR_ray_query with rayQuery on the device (not "
                "enabled by the application) to trace KHR top levels");
    return true;
}

// The application's device extensions split into what the driver is asked for and what the
// layer serves itself.
struct RequestedExtensions {
    std::vector<const char*> for_driver;
    bool cluster_extension = false;  // VK_NV_cluster_acceleration_structure asked for
    bool cluster_feature = false;    // and its feature struct says clusterAccelerationStructure
    bool frame_boundary_served = false;
};

RequestedExtensions sort_requested_extensions(InstanceState& instance,
                                              VkPhysicalDevice physical_device,
                                              const VkDeviceCreateInfo& info, bool serving) {
    RequestedExtensions r;
    for (uint32_t i = 0; i < info.enabledExtensionCount; ++i) {
        const char* name = info.ppEnabledExtensionNames[i];
        if (std::strcmp(name, VK_NV_CLUSTER_ACCELERATION_STRUCTURE_EXTENSION_NAME) == 0) {
            r.cluster_extension = true;
            if (serving) continue;  // the driver does not know it; the layer provides it
        }
        // VK_EXT_frame_boundary: the layer provides it where the driver lacks it.
        if (std::strcmp(name, VK_EXT_FRAME_BOUNDARY_EXTENSION_NAME) == 0 &&
            !driver_lists_extension(instance, physical_device,
                                    VK_EXT_FRAME_BOUNDARY_EXTENSION_NAME)) {
            r.frame_boundary_served = true;
            continue;
        }
        r.for_driver.push_back(name);
    }
    for (auto* s = (const VkBaseInStructure*)info.pNext; s; s = s->pNext)
        if (s->sType ==
            VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_CLUSTER_ACCELERATION_STRUCTURE_FEATURES_NV)
            r.cluster_feature = ((const VkPhysicalDeviceClusterAccelerationStructureFeaturesNV*)s)
                                    ->clusterAccelerationStructure == VK_TRUE;
    return r;
}

// GPU timestamps around captured commands need every queue family the device uses to count
// time, and the four query entry points.
void set_up_timestamps(const VkDeviceCreateInfo& info, DeviceState& state) {
    if (!info.queueCreateInfoCount) return;
    const InstanceState& instance = *state.instance;
    uint32_t family_count = 0;
    instance.next.GetPhysicalDeviceQueueFamilyProperties(state.physical_device, &family_count,
                                                         nullptr);
    std::vector<VkQueueFamilyProperties> families(family_count);
    instance.next.GetPhysicalDeviceQueueFamilyProperties(state.physical_device, &family_count,
                                                         families.data());
    uint32_t valid_bits = 64;
    for (uint32_t i = 0; i < info.queueCreateInfoCount; ++i) {
        const uint32_t family = info.pQueueCreateInfos[i].queueFamilyIndex;
        valid_bits =
            std::min(valid_bits, family < family_count ? families[family].timestampValidBits : 0u);
    }
    state.timestamps = valid_bits != 0 && state.next.CreateQueryPool &&
                       state.next.CmdWriteTimestamp && state.next.CmdResetQueryPool &&
                       state.next.GetQueryPoolResults;
    state.timestamp_mask = valid_bits >= 64 ? ~0ull : (1ull << valid_bits) - 1;
}

DeviceRecord device_record(const VkDeviceCreateInfo& info,
                           const VkPhysicalDeviceProperties& properties, DeviceState& state,
                           bool cluster_feature_enabled) {
    InstanceState& instance = *state.instance;
    DeviceRecord record;
    record.device = handle_id(state.device);
    record.device_name = properties.deviceName;
    record.application_name = instance.application_name;
    record.engine_name = instance.engine_name;
    record.api_version = properties.apiVersion;
    record.vendor_id = properties.vendorID;
    record.device_id = properties.deviceID;
    record.driver_version = properties.driverVersion;
    record.device_type = properties.deviceType;
    record.pipeline_cache_uuid.assign(properties.pipelineCacheUUID,
                                      properties.pipelineCacheUUID + VK_UUID_SIZE);
    record.timestamp_period = properties.limits.timestampPeriod;
    record.memory_heaps.assign(state.memory_properties.memoryHeaps,
                               state.memory_properties.memoryHeaps +
                                   state.memory_properties.memoryHeapCount);
    for (uint32_t i = 0; i < info.enabledExtensionCount; ++i)
        record.enabled_extensions.push_back(info.ppEnabledExtensionNames[i]);
    // Serving matters to the trace only when the application uses the served extension: an NV
    // ray-tracing program on a driver without it is a plain native capture.
    record.served_by_layer = state.serving && state.cluster_enabled;
    record.cluster_properties = state.cluster_properties;
    record.cluster_feature_enabled = cluster_feature_enabled;
    record.memory_types.assign(state.memory_properties.memoryTypes,
                               state.memory_properties.memoryTypes +
                                   state.memory_properties.memoryTypeCount);
    fill_driver_identity(instance, state.physical_device, properties.apiVersion, state, record);
    return record;
}

VKAPI_ATTR VkResult VKAPI_CALL CreateDevice(VkPhysicalDevice physical_device,
                                            const VkDeviceCreateInfo* p_create_info,
                                            const VkAllocationCallbacks* p_allocator,
                                            VkDevice* pDevice) {
    InstanceState* instance = find_instance(dispatch_key(physical_device));
    auto* link = find_layer_link<VkDeviceCreateInfo, VkLayerDeviceCreateInfo>(
        p_create_info, VK_STRUCTURE_TYPE_LOADER_DEVICE_CREATE_INFO);
    if (!instance || !link || !link->u.pLayerInfo) return VK_ERROR_INITIALIZATION_FAILED;
    PFN_vkGetInstanceProcAddr next_gipa = link->u.pLayerInfo->pfnNextGetInstanceProcAddr;
    PFN_vkGetDeviceProcAddr nextGdpa = link->u.pLayerInfo->pfnNextGetDeviceProcAddr;
    auto next_create = (PFN_vkCreateDevice)next_gipa(instance->instance, "vkCreateDevice");
    if (!next_create) return VK_ERROR_INITIALIZATION_FAILED;
    link->u.pLayerInfo = link->u.pLayerInfo->pNext;

    const bool serving = should_serve(*instance, physical_device);
    const RequestedExtensions requested =
        sort_requested_extensions(*instance, physical_device, *p_create_info, serving);
    const bool cluster_extension_requested = requested.cluster_extension;
    const bool frame_boundary_served = requested.frame_boundary_served;
    std::vector<const char*> extensions = requested.for_driver;

    VkDeviceCreateInfo driver_info = *p_create_info;
    driver_info.enabledExtensionCount = uint32_t(extensions.size());
    driver_info.ppEnabledExtensionNames = extensions.data();
    VkPhysicalDeviceRayQueryFeaturesKHR ray_query_feature{};
    const bool ray_query = enable_ray_query_for_check(*instance, physical_device, extensions,
                                                      driver_info, ray_query_feature);
    VkResult result;
    {
        // A served feature struct is unknown to the driver: hide it from the driver's view only.
        ChainUnlink hide_features(
            serving ? &driver_info : nullptr,
            VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_CLUSTER_ACCELERATION_STRUCTURE_FEATURES_NV);
        ChainUnlink hide_frame_boundary(
            frame_boundary_served ? &driver_info : nullptr,
            VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_FRAME_BOUNDARY_FEATURES_EXT);
        result = next_create(physical_device, &driver_info, p_allocator, pDevice);
    }
    if (result != VK_SUCCESS) return result;

    auto state = std::make_unique<DeviceState>();
    state->device = *pDevice;
    state->physical_device = physical_device;
    state->instance = instance;
#define CLASTRACE_LOAD(name) state->next.name = (PFN_vk##name)nextGdpa(*pDevice, "vk" #name);
    CLASTRACE_DEVICE_FUNCTIONS(CLASTRACE_LOAD)
#undef CLASTRACE_LOAD
    state->next.GetDeviceProcAddr = nextGdpa;
    if (serving) {  // whatever the driver answers for these names, the layer owns them
        state->next.CmdBuildClusterAccelerationStructureIndirectNV = nullptr;
        state->next.GetClusterAccelerationStructureBuildSizesNV = nullptr;
    }
    state->serving = serving;
    state->cluster_enabled = cluster_extension_requested;
    state->frame_boundary_served = frame_boundary_served;
    state->ray_query_enabled = ray_query;

    VkPhysicalDeviceProperties properties{};
    instance->next.GetPhysicalDeviceProperties(physical_device, &properties);
    instance->next.GetPhysicalDeviceMemoryProperties(physical_device, &state->memory_properties);
    state->non_coherent_atom_size =
        properties.limits.nonCoherentAtomSize ? properties.limits.nonCoherentAtomSize : 1;
    state->cluster_properties = cluster_properties_for(*instance, physical_device, serving);
    for (uint32_t i = 0; i < p_create_info->enabledExtensionCount; ++i)
        if (std::strcmp(p_create_info->ppEnabledExtensionNames[i],
                        VK_NV_RAY_TRACING_EXTENSION_NAME) == 0)
            state->nv_ray_tracing_enabled = true;

    const LayerConfig& config = layer_config();
    if (config.capture) state->sink = process_capture_sink();
    state->capturing = state->sink != nullptr;
    if (state->capturing && config.timestamps) set_up_timestamps(*p_create_info, *state);
    set_up_traceable_clusters(*state);  // before the pause worker, which builds with it
    if (state->capturing || serving) state->pauses = std::make_unique<PauseWorker>(*state);
    log_message(LogLevel::kInfo, "device %s: serving %s, capture %s, timestamps %s",
                properties.deviceName, serving ? "on" : "off", state->capturing ? "on" : "off",
                state->timestamps ? "on" : "off");

    if (state->sink) {
        state->sink->device_created(
            device_record(*p_create_info, properties, *state,
                          cluster_extension_requested && requested.cluster_feature));
    }
    register_device(dispatch_key(*pDevice), std::move(state));
    return VK_SUCCESS;
}

VKAPI_ATTR void VKAPI_CALL DestroyDevice(VkDevice device,
                                         const VkAllocationCallbacks* p_allocator) {
    auto state = unregister_device(dispatch_key(device));
    if (!state) return;
    state->pauses.reset();  // stops the worker before the device's events go away
    if (state->sink) {
        state->sink->device_destroyed(handle_id(device));
        state->sink->flush();
    }
    if (layer_config().stats) {  // after the flush, so the trace's numbers are final
        std::vector<std::string> extra =
            state->sink ? state->sink->cost_lines() : std::vector<std::string>{};
        extra.push_back(layer_config().host_writes ? state->host_writes.mode_line()
                                                   : "host-write watch: off");
        if (layer_config().host_writes)
            for (std::string& line : state->host_writes.phase_lines())
                extra.push_back(std::move(line));
        for (const std::string& line : cost_report(extra))
            std::fprintf(stderr, "clastrace: %s\n", line.c_str());
    }
    for (auto& [commandBuffer, log] : state->command_buffers)
        release_command_buffer_log(*state, *log);
    forget_khr_device(*state);  // the one per-device table kept outside DeviceState
    PFN_vkDestroyDevice destroy = state->next.DestroyDevice;
    state.reset();  // frees the layer's events and mappings while the device still exists
    destroy(device, p_allocator);
}

VKAPI_ATTR PFN_vkVoidFunction VKAPI_CALL GetDeviceProcAddr(VkDevice device, const char* p_name);

VKAPI_ATTR PFN_vkVoidFunction VKAPI_CALL GetInstanceProcAddr(VkInstance instance,
                                                             const char* p_name) {
    if (std::strcmp(p_name, "vkGetInstanceProcAddr") == 0)
        return (PFN_vkVoidFunction)GetInstanceProcAddr;
    if (std::strcmp(p_name, "vkCreateInstance") == 0) return (PFN_vkVoidFunction)CreateInstance;
    if (std::strcmp(p_name, "vkDestroyInstance") == 0) return (PFN_vkVoidFunction)DestroyInstance;
    if (std::strcmp(p_name, "vkCreateDevice") == 0) return (PFN_vkVoidFunction)CreateDevice;
    if (std::strcmp(p_name, "vkGetDeviceProcAddr") == 0)
        return (PFN_vkVoidFunction)GetDeviceProcAddr;
    if (std::strcmp(p_name, "vkDestroyDevice") == 0) return (PFN_vkVoidFunction)DestroyDevice;
    if (!instance) return nullptr;
    InstanceState* state = find_instance(dispatch_key(instance));
    if (!state) return nullptr;
    PFN_vkVoidFunction next = state->next.GetInstanceProcAddr(instance, p_name);
    if (PFN_vkVoidFunction hook = serving_instance_hook(p_name)) return next ? hook : nullptr;
    // Device functions asked through the instance: ours only where the driver chain has them,
    // except the served extension's, which the layer provides on its own.
    if (PFN_vkVoidFunction hook = intercept_device_function(p_name, nullptr))
        return next ? hook : next;
    if (std::strcmp(p_name, "vkCmdBuildClusterAccelerationStructureIndirectNV") == 0 ||
        std::strcmp(p_name, "vkGetClusterAccelerationStructureBuildSizesNV") == 0)
        return layer_config().serve != ServeMode::kOff ? cluster_hook(p_name) : next;
    return next;
}

VKAPI_ATTR PFN_vkVoidFunction VKAPI_CALL GetDeviceProcAddr(VkDevice device, const char* p_name) {
    if (std::strcmp(p_name, "vkGetDeviceProcAddr") == 0)
        return (PFN_vkVoidFunction)GetDeviceProcAddr;
    if (std::strcmp(p_name, "vkDestroyDevice") == 0) return (PFN_vkVoidFunction)DestroyDevice;
    if (!device) return nullptr;
    DeviceState* state = find_device(dispatch_key(device));
    if (!state) return nullptr;
    if (PFN_vkVoidFunction hook = intercept_device_function(p_name, state)) return hook;
    return state->next.GetDeviceProcAddr(device, p_name);
}

std::mutex sinkMutex;
// Kept for the whole process: a trace is finished (index and trailer written) when the
// sink is destroyed, at exit or when the loader unloads the layer, so a second device of
// the same process appends to the same trace instead of truncating it.
std::shared_ptr<CaptureSink> sharedSink;
bool sinkFailed = false;

}  // namespace

// At exit without vkDestroyDevice the registry's destructor gets here first: the worker must
// stop before the members it reads (command buffers, descriptors, device B) go, in reverse
// declaration order, ahead of it.
DeviceState::~DeviceState() { pauses.reset(); }

namespace {
std::atomic<uint64_t> submissionCounter{0};
std::mutex preludeIndicesMutex;
std::vector<uint64_t> preludeIndices;  // ascending: the layer's own prelude submissions
}  // namespace

uint64_t next_submission_index() { return submissionCounter++; }

uint64_t index_after_prelude(uint64_t prelude_index) {
    std::lock_guard lock(preludeIndicesMutex);
    preludeIndices.push_back(prelude_index);
    return submissionCounter++;
}

uint64_t application_submission(uint64_t index) {
    std::lock_guard lock(preludeIndicesMutex);
    uint64_t before = 0;
    for (uint64_t p : preludeIndices) before += p < index;
    return index - before;
}

InstanceState* find_instance(DispatchKey key) {
    std::shared_lock lock(registryMutex);
    auto it = instances().find(key);
    return it == instances().end() ? nullptr : it->second.get();
}
DeviceState* find_device(DispatchKey key) {
    std::shared_lock lock(registryMutex);
    auto it = devices().find(key);
    return it == devices().end() ? nullptr : it->second.get();
}
void register_instance(DispatchKey key, std::unique_ptr<InstanceState> state) {
    std::unique_lock lock(registryMutex);
    instances()[key] = std::move(state);
}
std::unique_ptr<InstanceState> unregister_instance(DispatchKey key) {
    std::unique_lock lock(registryMutex);
    auto it = instances().find(key);
    if (it == instances().end()) return nullptr;
    auto state = std::move(it->second);
    instances().erase(it);
    return state;
}
void register_device(DispatchKey key, std::unique_ptr<DeviceState> state) {
    std::unique_lock lock(registryMutex);
    devices()[key] = std::move(state);
}
std::unique_ptr<DeviceState> unregister_device(DispatchKey key) {
    std::unique_lock lock(registryMutex);
    auto it = devices().find(key);
    if (it == devices().end()) return nullptr;
    auto state = std::move(it->second);
    devices().erase(it);
    return state;
}

void log_message(LogLevel level, const char* format, ...) {
    if (int(level) > int(layer_config().log)) return;
    char text[1024];
    va_list args;
    va_start(args, format);
    std::vsnprintf(text, sizeof text, format, args);
    va_end(args);
    std::fprintf(stderr, "clastrace: %s\n", text);
}

std::shared_ptr<CaptureSink> process_capture_sink() {
    std::lock_guard lock(sinkMutex);
    if (sharedSink) return sharedSink;
    if (sinkFailed) return nullptr;
    const LayerConfig& config = layer_config();
    std::string error;
    std::shared_ptr<CaptureSink> sink;
    if (!config.debug_json_path.empty()) {
        sink = make_json_capture_sink(config.debug_json_path, error);
    } else if (!config.output_path.empty()) {
        // Decided on the application's thread creating the device: its affinity is the application's.
        BackgroundPlacement placement;
        placement.application_cpus = calling_thread_cpus();
        placement.application_siblings = smt_siblings(placement.application_cpus);
        placement.cpus =
            background_cpus_for(config.background_cpus, online_cpus(), placement.application_cpus,
                                reserved_cpus(), placement.application_siblings);
        log_message(LogLevel::kInfo, "background threads: CPUs %s (the application's: %s)",
                    placement.cpus.empty() ? "of the application"
                                           : format_cpu_list(placement.cpus).c_str(),
                    format_cpu_list(placement.application_cpus).c_str());
        sink = make_trace_capture_sink(config.output_path, config.zstd_level, error,
                                       config.flush_milliseconds, std::move(placement),
                                       config.output_fd);
    } else {
        // Serving alone is a normal use (CI drivers): no output named means no capture, quietly.
        sinkFailed = true;
        log_message(LogLevel::kInfo, "capture off: CLASTRACE_OUTPUT is not set");
        return nullptr;
    }
    if (!sink) {
        sinkFailed = true;  // one message per process, then the application runs without capture
        std::fprintf(stderr,
                     "clastrace: capture disabled: %s; the application continues without capture\n",
                     error.c_str());
        return nullptr;
    }
    sharedSink = sink;
    return sink;
}

PFN_vkVoidFunction intercept_device_function(const char* name, DeviceState* device) {
    if (std::strcmp(name, "vkCmdBuildClusterAccelerationStructureIndirectNV") == 0 ||
        std::strcmp(name, "vkGetClusterAccelerationStructureBuildSizesNV") == 0) {
        if (!device) return nullptr;  // GetInstanceProcAddr decides these itself
        const bool native =
            std::strcmp(name, "vkGetClusterAccelerationStructureBuildSizesNV") == 0
                ? device->next.GetClusterAccelerationStructureBuildSizesNV != nullptr
                : device->next.CmdBuildClusterAccelerationStructureIndirectNV != nullptr;
        return device->serving || native ? cluster_hook(name) : nullptr;
    }
    PFN_vkVoidFunction hook = resource_hook(name);
    if (!hook) hook = acceleration_structure_hook(name);
    if (!hook) hook = command_hook(name);
    if (!hook) hook = pipeline_hook(name);
    if (!hook) hook = draw_hook(name);
    if (!hook) hook = submit_hook(name);
    if (!hook) hook = host_sync_hook(name);
    if (!hook) hook = present_hook(name);
    if (!hook) hook = sparse_hook(name);
    if (!hook) hook = khr_acceleration_structure_hook(name);
    if (!hook) hook = consumer_hook(name);
    if (!hook) hook = consumer_pipeline_hook(name);
    if (!hook) hook = descriptor_template_hook(name);
    if (!hook || !device) return hook;
    // Forward only what the driver chain has: the hook would call a null pointer otherwise.
    return device->next.GetDeviceProcAddr(device->device, name) ? hook : nullptr;
}

}  // namespace clastrace::capture

using namespace clastrace::capture;

extern "C" __attribute__((visibility("default"))) VKAPI_ATTR VkResult VKAPI_CALL
vkNegotiateLoaderLayerInterfaceVersion(VkNegotiateLayerInterface* p_version_struct) {
    if (!p_version_struct || p_version_struct->sType != LAYER_NEGOTIATE_INTERFACE_STRUCT)
        return VK_ERROR_INITIALIZATION_FAILED;
    // Version 2 is the first with the negotiated proc-address functions; nothing newer is needed.
    if (p_version_struct->loaderLayerInterfaceVersion < 2) return VK_ERROR_INITIALIZATION_FAILED;
    p_version_struct->loaderLayerInterfaceVersion = 2;
    p_version_struct->pfnGetInstanceProcAddr = GetInstanceProcAddr;
    p_version_struct->pfnGetDeviceProcAddr = GetDeviceProcAddr;
    p_version_struct->pfnGetPhysicalDeviceProcAddr = nullptr;
    return VK_SUCCESS;
}
