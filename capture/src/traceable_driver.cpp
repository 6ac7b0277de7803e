// SPDX-License-Identifier: Apache-2.0
// Device B of the traceable mode (traceable_clusters.h): the driver library driven directly,
// below the loader, so nothing the layer does here is seen by the application's layer chain.
#include "traceable_clusters.h"

#include <dlfcn.h>

#include <algorithm>
#include <cstdlib>
#include <cstring>

namespace clastrace::capture {

// Every build is one batch (traceable_build.cpp); the functions B is driven with:
#define CLASTRACE_TRACEABLE_FUNCTIONS(X)      \
    X(DestroyInstance)                        \
    X(EnumeratePhysicalDevices)               \
    X(GetPhysicalDeviceProperties2)           \
    X(GetPhysicalDeviceQueueFamilyProperties) \
    X(GetPhysicalDeviceMemoryProperties)      \
    X(EnumerateDeviceExtensionProperties)     \
    X(CreateDevice)                           \
    X(GetDeviceProcAddr)                      \
    X(DestroyDevice)                          \
    X(GetDeviceQueue)                         \
    X(CreateCommandPool)                      \
    X(DestroyCommandPool)                     \
    X(AllocateCommandBuffers)                 \
    X(FreeCommandBuffers)                     \
    X(BeginCommandBuffer)                     \
    X(EndCommandBuffer)                       \
    X(QueueSubmit)                            \
    X(QueueWaitIdle)                          \
    X(AllocateMemory)                         \
    X(FreeMemory)                             \
    X(MapMemory)                              \
    X(CreateBuffer)                           \
    X(DestroyBuffer)                          \
    X(BindBufferMemory)                       \
    X(GetBufferMemoryRequirements)            \
    X(GetBufferDeviceAddress)                 \
    X(GetMemoryHostPointerPropertiesEXT)      \
    X(CreateAccelerationStructureKHR)         \
    X(DestroyAccelerationStructureKHR)        \
    X(GetAccelerationStructureBuildSizesKHR)  \
    X(CmdBuildAccelerationStructuresKHR)      \
    X(GetAccelerationStructureDeviceAddressKHR)

struct TraceableDriver::Functions {
#define CLASTRACE_MEMBER(name) PFN_vk##name name = nullptr;
    CLASTRACE_TRACEABLE_FUNCTIONS(CLASTRACE_MEMBER)
#undef CLASTRACE_MEMBER
};

namespace {

constexpr const char* kExtensions[] = {VK_KHR_ACCELERATION_STRUCTURE_EXTENSION_NAME,
                                       VK_KHR_DEFERRED_HOST_OPERATIONS_EXTENSION_NAME,
                                       VK_KHR_RAY_QUERY_EXTENSION_NAME,
                                       VK_EXT_EXTERNAL_MEMORY_HOST_EXTENSION_NAME};
constexpr uint64_t kAccelerationStructureAlignment = 256;  // VkAccelerationStructureCreateInfoKHR

uint64_t align_up(uint64_t value, uint64_t alignment) {
    return (value + alignment - 1) / alignment * alignment;
}

}  // namespace

TraceableMode traceable_mode_from_environment() {
    const char* value = std::getenv("CLASTRACE_TRACEABLE_CLUSTERS");
    if (!value || !*value || std::strcmp(value, "auto") == 0) return TraceableMode::kAuto;
    if (std::strcmp(value, "0") == 0) return TraceableMode::kOff;
    return TraceableMode::kOn;
}

TraceableDriver::TraceableDriver() : vk_(std::make_unique<Functions>()) {}

TraceableDriver::~TraceableDriver() {
    if (pool_) vk_->DestroyCommandPool(device_, pool_, nullptr);
    if (device_) vk_->DestroyDevice(device_, nullptr);
    if (instance_) vk_->DestroyInstance(instance_, nullptr);
    if (library_) dlclose(library_);
}

std::unique_ptr<TraceableDriver> TraceableDriver::probe(PFN_vkVoidFunction any_driver_function,
                                                        const uint8_t device_uuid[VK_UUID_SIZE],
                                                        std::string& why) {
    Dl_info where{};
    if (!any_driver_function || !dladdr((void*)any_driver_function, &where) || !where.dli_fname) {
        why = "the driver library is not known";
        return nullptr;
    }
    std::unique_ptr<TraceableDriver> driver(new TraceableDriver);
    driver->library_ = dlopen(where.dli_fname, RTLD_NOW | RTLD_LOCAL | RTLD_NOLOAD);
    if (!driver->library_) {
        why = std::string("cannot open ") + where.dli_fname;
        return nullptr;
    }
    if (!driver->create_device(device_uuid, why) || !driver->prove(why)) return nullptr;
    return driver;
}

bool TraceableDriver::create_device(const uint8_t device_uuid[VK_UUID_SIZE], std::string& why) {
    auto gipa = (PFN_vkGetInstanceProcAddr)dlsym(library_, "vk_icdGetInstanceProcAddr");
    auto create_instance = gipa ? (PFN_vkCreateInstance)gipa(nullptr, "vkCreateInstance") : nullptr;
    if (!create_instance) {
        why = "the driver library has no vk_icdGetInstanceProcAddr";
        return false;
    }
    VkApplicationInfo application{VK_STRUCTURE_TYPE_APPLICATION_INFO};
    application.pApplicationName = "clastrace traceable clusters";
    application.apiVersion = VK_API_VERSION_1_3;
    VkInstanceCreateInfo instance_info{VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO};
    instance_info.pApplicationInfo = &application;
    if (create_instance(&instance_info, nullptr, &instance_) != VK_SUCCESS) {
        why = "the driver library refused an instance";
        return false;
    }
    auto destroy_instance = (PFN_vkDestroyInstance)gipa(instance_, "vkDestroyInstance");
    vk_->DestroyInstance = destroy_instance;
#define CLASTRACE_LOAD_INSTANCE(name) \
    if (!vk_->name) vk_->name = (PFN_vk##name)gipa(instance_, "vk" #name);
    CLASTRACE_TRACEABLE_FUNCTIONS(CLASTRACE_LOAD_INSTANCE)
#undef CLASTRACE_LOAD_INSTANCE
    uint32_t count = 0;
    vk_->EnumeratePhysicalDevices(instance_, &count, nullptr);
    std::vector<VkPhysicalDevice> devices(count);
    vk_->EnumeratePhysicalDevices(instance_, &count, devices.data());
    for (VkPhysicalDevice candidate : devices) {
        VkPhysicalDeviceIDProperties ids{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_ID_PROPERTIES};
        VkPhysicalDeviceExternalMemoryHostPropertiesEXT host{
            VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_EXTERNAL_MEMORY_HOST_PROPERTIES_EXT, &ids};
        VkPhysicalDeviceProperties2 properties{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2,
                                               &host};
        vk_->GetPhysicalDeviceProperties2(candidate, &properties);
        if (std::memcmp(ids.deviceUUID, device_uuid, VK_UUID_SIZE) != 0) continue;
        physical_ = candidate;
        import_alignment_ = std::max<uint64_t>(host.minImportedHostPointerAlignment, 1);
    }
    if (!physical_) {
        why = "the driver library does not list the application's device";
        return false;
    }
    vk_->EnumerateDeviceExtensionProperties(physical_, nullptr, &count, nullptr);
    std::vector<VkExtensionProperties> offered(count);
    vk_->EnumerateDeviceExtensionProperties(physical_, nullptr, &count, offered.data());
    for (const char* name : kExtensions)
        if (std::none_of(offered.begin(), offered.end(), [&](const VkExtensionProperties& e) {
                return std::strcmp(e.extensionName, name) == 0;
            })) {
            why = std::string("the driver lacks ") + name;
            return false;
        }
    vk_->GetPhysicalDeviceQueueFamilyProperties(physical_, &count, nullptr);
    std::vector<VkQueueFamilyProperties> families(count);
    vk_->GetPhysicalDeviceQueueFamilyProperties(physical_, &count, families.data());
    queue_family_ = count;
    for (uint32_t f = 0; f < count && queue_family_ == count; ++f)
        if (families[f].queueFlags & VK_QUEUE_COMPUTE_BIT) queue_family_ = f;
    if (queue_family_ == count) {
        why = "the device has no compute queue";
        return false;
    }
    vk_->GetPhysicalDeviceMemoryProperties(physical_, &memory_);

    const float priority = 1.0f;
    VkDeviceQueueCreateInfo queue_info{VK_STRUCTURE_TYPE_DEVICE_QUEUE_CREATE_INFO};
    queue_info.queueFamilyIndex = queue_family_;
    queue_info.queueCount = 1;
    queue_info.pQueuePriorities = &priority;
    // B must enable ray query to be answered BLAS sizes (issue 21's experiment).
    VkPhysicalDeviceRayQueryFeaturesKHR ray_query{
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_RAY_QUERY_FEATURES_KHR};
    ray_query.rayQuery = VK_TRUE;
    VkPhysicalDeviceAccelerationStructureFeaturesKHR structures{
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_ACCELERATION_STRUCTURE_FEATURES_KHR, &ray_query};
    structures.accelerationStructure = VK_TRUE;
    VkPhysicalDeviceVulkan12Features vulkan12{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_2_FEATURES,
                                              &structures};
    vulkan12.bufferDeviceAddress = VK_TRUE;
    VkDeviceCreateInfo device_info{VK_STRUCTURE_TYPE_DEVICE_CREATE_INFO, &vulkan12};
    device_info.queueCreateInfoCount = 1;
    device_info.pQueueCreateInfos = &queue_info;
    device_info.enabledExtensionCount = uint32_t(std::size(kExtensions));
    device_info.ppEnabledExtensionNames = kExtensions;
    if (vk_->CreateDevice(physical_, &device_info, nullptr, &device_) != VK_SUCCESS) {
        why = "the driver refused device B";
        return false;
    }
#define CLASTRACE_LOAD_DEVICE(name) \
    if (auto f = (PFN_vk##name)vk_->GetDeviceProcAddr(device_, "vk" #name)) vk_->name = f;
    CLASTRACE_TRACEABLE_FUNCTIONS(CLASTRACE_LOAD_DEVICE)
#undef CLASTRACE_LOAD_DEVICE
#define CLASTRACE_CHECK_LOADED(name)       \
    if (!vk_->name) {                      \
        why = "the driver lacks vk" #name; \
        return false;                      \
    }
    CLASTRACE_TRACEABLE_FUNCTIONS(CLASTRACE_CHECK_LOADED)
#undef CLASTRACE_CHECK_LOADED
    vk_->GetDeviceQueue(device_, queue_family_, 0, &queue_);
    VkCommandPoolCreateInfo pool_info{VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO};
    pool_info.flags = VK_COMMAND_POOL_CREATE_RESET_COMMAND_BUFFER_BIT;
    pool_info.queueFamilyIndex = queue_family_;
    if (vk_->CreateCommandPool(device_, &pool_info, nullptr, &pool_) != VK_SUCCESS) {
        why = "no command pool on device B";
        return false;
    }
    return true;
}

// A tiny BLAS (one triangle) built into host memory B imports: the structure's address must be
// the host address it was placed at, which is what lets the application's device find it.
bool TraceableDriver::prove(std::string& why) {
    const uint64_t size = align_up(64 << 10, import_alignment_);
    void* host = std::aligned_alloc(import_alignment_, size);
    if (!host) {
        why = "out of host memory";
        return false;
    }
    std::memset(host, 0, size);
    TraceableBatch batch;
    TraceableBlasGeometry blas;
    blas.host = static_cast<uint8_t*>(host) + kAccelerationStructureAlignment;
    blas.address = reinterpret_cast<uint64_t>(blas.host);
    blas.room = size - kAccelerationStructureAlignment;
    blas.clusters.push_back({0, 0, 0, 1, 0, 0, 0, 1, 0});
    batch.blases.push_back(blas);
    const bool built = build(batch, why);
    const bool written =
        built && std::any_of(blas.host, blas.host + 64, [](uint8_t b) { return b != 0; });
    std::free(host);
    if (built && !written) why = "the BLAS built into imported memory left it untouched";
    return written;
}

uint64_t TraceableDriver::blas_size(uint32_t clusters, uint32_t triangles_per_cluster) {
    VkAccelerationStructureGeometryKHR geometry{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_KHR};
    geometry.geometryType = VK_GEOMETRY_TYPE_TRIANGLES_KHR;
    geometry.geometry.triangles.sType =
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_TRIANGLES_DATA_KHR;
    geometry.geometry.triangles.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    geometry.geometry.triangles.vertexStride = 12;
    geometry.geometry.triangles.maxVertex = triangles_per_cluster * 3;
    geometry.geometry.triangles.indexType = VK_INDEX_TYPE_NONE_KHR;
    const std::vector<VkAccelerationStructureGeometryKHR> geometries(clusters, geometry);
    const std::vector<uint32_t> counts(clusters, triangles_per_cluster);
    VkAccelerationStructureBuildGeometryInfoKHR info{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_GEOMETRY_INFO_KHR};
    info.type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR;
    info.mode = VK_BUILD_ACCELERATION_STRUCTURE_MODE_BUILD_KHR;
    info.geometryCount = clusters;
    info.pGeometries = geometries.data();
    VkAccelerationStructureBuildSizesInfoKHR sizes{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_SIZES_INFO_KHR};
    vk_->GetAccelerationStructureBuildSizesKHR(device_,
                                               VK_ACCELERATION_STRUCTURE_BUILD_TYPE_DEVICE_KHR,
                                               &info, counts.data(), &sizes);
    return sizes.accelerationStructureSize;
}


// `import`: host memory (aligned to the import alignment, `size` a multiple of it) the buffer
// takes as its memory instead of allocating; otherwise host-visible memory, mapped.
bool TraceableDriver::allocate(VkDeviceSize size, VkBufferUsageFlags usage, void* import,
                               TraceableBuffer& out, std::string& why) {
    VkExternalMemoryBufferCreateInfo external{VK_STRUCTURE_TYPE_EXTERNAL_MEMORY_BUFFER_CREATE_INFO};
    external.handleTypes = VK_EXTERNAL_MEMORY_HANDLE_TYPE_HOST_ALLOCATION_BIT_EXT;
    VkBufferCreateInfo buffer_info{VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO,
                                   import ? &external : nullptr};
    buffer_info.size = size;
    buffer_info.usage = usage | VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT;
    if (vk_->CreateBuffer(device_, &buffer_info, nullptr, &out.buffer) != VK_SUCCESS) {
        why = "device B refused a buffer";
        return false;
    }
    VkMemoryRequirements requirements;
    vk_->GetBufferMemoryRequirements(device_, out.buffer, &requirements);
    uint32_t type_bits = requirements.memoryTypeBits;
    VkImportMemoryHostPointerInfoEXT imported{
        VK_STRUCTURE_TYPE_IMPORT_MEMORY_HOST_POINTER_INFO_EXT};
    if (import) {
        VkMemoryHostPointerPropertiesEXT pointer{
            VK_STRUCTURE_TYPE_MEMORY_HOST_POINTER_PROPERTIES_EXT};
        if (vk_->GetMemoryHostPointerPropertiesEXT(
                device_, VK_EXTERNAL_MEMORY_HANDLE_TYPE_HOST_ALLOCATION_BIT_EXT, import,
                &pointer) != VK_SUCCESS) {
            why = "device B cannot import the destination's host memory";
            return false;
        }
        type_bits &= pointer.memoryTypeBits;
        imported.handleType = VK_EXTERNAL_MEMORY_HANDLE_TYPE_HOST_ALLOCATION_BIT_EXT;
        imported.pHostPointer = import;
    }
    uint32_t type = 0;
    while (type < memory_.memoryTypeCount &&
           !((type_bits >> type & 1) &&
             (memory_.memoryTypes[type].propertyFlags & VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT)))
        ++type;
    VkMemoryAllocateFlagsInfo flags{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_FLAGS_INFO,
                                    import ? &imported : nullptr,
                                    VK_MEMORY_ALLOCATE_DEVICE_ADDRESS_BIT, 0};
    VkMemoryAllocateInfo memory_info{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO, &flags,
                                     import ? size : requirements.size, type};
    if (type == memory_.memoryTypeCount ||
        vk_->AllocateMemory(device_, &memory_info, nullptr, &out.memory) != VK_SUCCESS ||
        vk_->BindBufferMemory(device_, out.buffer, out.memory, 0) != VK_SUCCESS ||
        (!import &&
         vk_->MapMemory(device_, out.memory, 0, VK_WHOLE_SIZE, 0, &out.mapped) != VK_SUCCESS)) {
        why = import ? "device B cannot import the destination's pages"
                     : "device B has no host-visible memory for the build";
        return false;
    }
    VkBufferDeviceAddressInfo address{VK_STRUCTURE_TYPE_BUFFER_DEVICE_ADDRESS_INFO, nullptr,
                                      out.buffer};
    out.address = vk_->GetBufferDeviceAddress(device_, &address);
    return true;
}

void TraceableDriver::release(TraceableBuffer& owned) {
    if (owned.buffer) vk_->DestroyBuffer(device_, owned.buffer, nullptr);
    if (owned.memory) vk_->FreeMemory(device_, owned.memory, nullptr);  // (unmaps)
    owned = {};
}

namespace {

// One BLAS's geometries as the driver takes them: cluster g's triangles from `vertices`.
struct DriverBlas {
    std::vector<VkAccelerationStructureGeometryKHR> geometries;
    std::vector<VkAccelerationStructureBuildRangeInfoKHR> ranges;
    VkAccelerationStructureBuildGeometryInfoKHR info{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_GEOMETRY_INFO_KHR};
    VkAccelerationStructureBuildSizesInfoKHR sizes{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_SIZES_INFO_KHR};
    std::vector<uint32_t> counts;
};

DriverBlas describe_blas(const TraceableBlasGeometry& blas, VkDeviceAddress vertices) {
    DriverBlas out;
    for (const std::vector<float>& cluster : blas.clusters) {
        const uint32_t triangles = uint32_t(cluster.size() / 9);
        VkAccelerationStructureGeometryKHR geometry{
            VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_KHR};
        geometry.geometryType = VK_GEOMETRY_TYPE_TRIANGLES_KHR;
        geometry.flags = VK_GEOMETRY_OPAQUE_BIT_KHR;
        auto& t = geometry.geometry.triangles;
        t.sType = VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_TRIANGLES_DATA_KHR;
        t.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
        t.vertexData.deviceAddress = vertices;
        t.vertexStride = 12;
        t.maxVertex = triangles ? triangles * 3 - 1 : 0;
        t.indexType = VK_INDEX_TYPE_NONE_KHR;
        out.geometries.push_back(geometry);
        out.ranges.push_back({triangles, 0, 0, 0});
        out.counts.push_back(triangles);
        vertices += cluster.size() * sizeof(float);
    }
    out.info.type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR;
    out.info.flags = VK_BUILD_ACCELERATION_STRUCTURE_PREFER_FAST_TRACE_BIT_KHR;
    out.info.mode = VK_BUILD_ACCELERATION_STRUCTURE_MODE_BUILD_KHR;
    out.info.geometryCount = uint32_t(out.geometries.size());
    out.info.pGeometries = out.geometries.data();
    return out;
}

}  // namespace

bool TraceableDriver::build(TraceableBatch& batch, std::string& why) {
    if (batch.blases.empty()) return true;
    uint64_t vertex_bytes = 0;
    for (const TraceableBlasGeometry& blas : batch.blases)
        for (const std::vector<float>& cluster : blas.clusters)
            vertex_bytes += cluster.size() * sizeof(float);
    TraceableBuffer vertices, scratch;
    std::vector<TraceableBuffer> destinations(batch.blases.size());
    std::vector<VkAccelerationStructureKHR> structures(batch.blases.size(), VK_NULL_HANDLE);
    std::vector<DriverBlas> blases;
    VkCommandBuffer commands = VK_NULL_HANDLE;
    bool ok = allocate(std::max<uint64_t>(vertex_bytes, 16),
                       VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR,
                       nullptr, vertices, why);
    uint64_t scratch_bytes = 0, vertex_offset = 0;
    for (size_t i = 0; ok && i < batch.blases.size(); ++i) {
        TraceableBlasGeometry& blas = batch.blases[i];
        const VkDeviceAddress first = vertices.address + vertex_offset;
        for (const std::vector<float>& cluster : blas.clusters) {
            std::memcpy(static_cast<uint8_t*>(vertices.mapped) + vertex_offset, cluster.data(),
                        cluster.size() * sizeof(float));
            vertex_offset += cluster.size() * sizeof(float);
        }
        blases.push_back(describe_blas(blas, first));
        DriverBlas& d = blases.back();
        vk_->GetAccelerationStructureBuildSizesKHR(device_,
                                                   VK_ACCELERATION_STRUCTURE_BUILD_TYPE_DEVICE_KHR,
                                                   &d.info, d.counts.data(), &d.sizes);
        if (reinterpret_cast<uint64_t>(blas.host) % kAccelerationStructureAlignment != 0 ||
            d.sizes.accelerationStructureSize > blas.room) {
            why = "the driver's BLAS does not fit its destination";
            ok = false;
            break;
        }
        blas.driver_size = d.sizes.accelerationStructureSize;
        const uint64_t host = reinterpret_cast<uint64_t>(blas.host);
        const uint64_t base = host / import_alignment_ * import_alignment_;
        const uint64_t end = align_up(host + d.sizes.accelerationStructureSize, import_alignment_);
        ok = allocate(end - base, VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR,
                      reinterpret_cast<void*>(base), destinations[i], why);
        VkAccelerationStructureCreateInfoKHR create{
            VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_CREATE_INFO_KHR};
        create.buffer = destinations[i].buffer;
        create.offset = host - base;
        create.size = d.sizes.accelerationStructureSize;
        create.type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR;
        if (ok && vk_->CreateAccelerationStructureKHR(device_, &create, nullptr, &structures[i]) !=
                      VK_SUCCESS) {
            why = "device B refused the BLAS object";
            ok = false;
        }
        VkAccelerationStructureDeviceAddressInfoKHR address{
            VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_DEVICE_ADDRESS_INFO_KHR, nullptr,
            structures[i]};
        if (ok && vk_->GetAccelerationStructureDeviceAddressKHR(device_, &address) != host) {
            why = "the BLAS's address on device B is not its host address";
            ok = false;
        }
        d.info.dstAccelerationStructure = structures[i];
        scratch_bytes = align_up(scratch_bytes, kAccelerationStructureAlignment);
        d.info.scratchData.deviceAddress = scratch_bytes;  // an offset until scratch exists
        scratch_bytes += d.sizes.buildScratchSize;
    }
    ok = ok && allocate(std::max<uint64_t>(scratch_bytes, 16), VK_BUFFER_USAGE_STORAGE_BUFFER_BIT,
                        nullptr, scratch, why);
    VkCommandBufferAllocateInfo command_info{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO,
                                             nullptr, pool_, VK_COMMAND_BUFFER_LEVEL_PRIMARY, 1};
    ok = ok && vk_->AllocateCommandBuffers(device_, &command_info, &commands) == VK_SUCCESS;
    if (ok) {
        std::vector<VkAccelerationStructureBuildGeometryInfoKHR> infos;
        std::vector<const VkAccelerationStructureBuildRangeInfoKHR*> ranges;
        for (DriverBlas& d : blases) {
            d.info.scratchData.deviceAddress += scratch.address;
            infos.push_back(d.info);
            ranges.push_back(d.ranges.data());
        }
        VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
        begin.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
        vk_->BeginCommandBuffer(commands, &begin);
        vk_->CmdBuildAccelerationStructuresKHR(commands, uint32_t(infos.size()), infos.data(),
                                               ranges.data());
        vk_->EndCommandBuffer(commands);
        VkSubmitInfo submit{VK_STRUCTURE_TYPE_SUBMIT_INFO};
        submit.commandBufferCount = 1;
        submit.pCommandBuffers = &commands;
        ok = vk_->QueueSubmit(queue_, 1, &submit, VK_NULL_HANDLE) == VK_SUCCESS &&
             vk_->QueueWaitIdle(queue_) == VK_SUCCESS;
        if (!ok) why = "device B's build did not complete";
    }
    if (commands) vk_->FreeCommandBuffers(device_, pool_, 1, &commands);
    for (VkAccelerationStructureKHR s : structures)
        if (s) vk_->DestroyAccelerationStructureKHR(device_, s, nullptr);
    for (TraceableBuffer& b : destinations) release(b);
    release(vertices);
    release(scratch);
    return ok;
}

}  // namespace clastrace::capture
