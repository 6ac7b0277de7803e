// SPDX-License-Identifier: Apache-2.0
// Bare Vulkan 1.3 set-up for the bug programs, written the way an engine outside this project
// would: one instance, one device with VK_NV_cluster_acceleration_structure (and, on request,
// VK_KHR_acceleration_structure), host-visible buffers with device addresses, one-shot command
// buffers. Nothing of tests/apps is used, so the programs carry none of our habits.
#pragma once

#include <clastrace/vk_cluster_abi.h>
#include <vulkan/vulkan.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

namespace bug_programs {

// The exit code that tells the test the driver lacks what the program needs (it skips).
inline constexpr int kUnsupported = 77;

[[noreturn]] inline void die(const char* what, VkResult result = VK_SUCCESS) {
    std::fprintf(stderr, "bug program: %s (VkResult %d)\n", what, int(result));
    std::exit(2);
}

[[noreturn]] inline void unsupported(const char* what) {
    std::fprintf(stderr, "bug program: unsupported here: %s\n", what);
    std::exit(kUnsupported);
}

inline void vk_ok(VkResult result, const char* call) {
    if (result != VK_SUCCESS) die(call, result);
}

// True when the program was started with `flag` (e.g. "--fixed": the variant without the bug).
inline bool has_flag(int argc, char** argv, const char* flag) {
    for (int i = 1; i < argc; ++i)
        if (std::strcmp(argv[i], flag) == 0) return true;
    return false;
}

struct Buffer {
    VkBuffer buffer = VK_NULL_HANDLE;
    VkDeviceMemory memory = VK_NULL_HANDLE;
    VkDeviceAddress address = 0;
    VkDeviceSize size = 0;
    unsigned char* host = nullptr;  // persistently mapped
};

struct Gpu {
    VkInstance instance = VK_NULL_HANDLE;
    VkPhysicalDevice physical = VK_NULL_HANDLE;
    VkDevice device = VK_NULL_HANDLE;
    uint32_t family = 0;
    VkQueue queue = VK_NULL_HANDLE;
    VkCommandPool pool = VK_NULL_HANDLE;
    VkPhysicalDeviceClusterAccelerationStructurePropertiesNV cluster_props{};
    PFN_vkCmdBuildClusterAccelerationStructureIndirectNV cmd_build_clusters = nullptr;
    PFN_vkGetClusterAccelerationStructureBuildSizesNV get_cluster_sizes = nullptr;
    bool khr_structures = false;  // VK_KHR_acceleration_structure enabled
    std::vector<Buffer> buffers;

    ~Gpu() {
        if (!device) return;
        vkDeviceWaitIdle(device);
        for (Buffer& b : buffers) {
            vkDestroyBuffer(device, b.buffer, nullptr);
            vkFreeMemory(device, b.memory, nullptr);
        }
        vkDestroyCommandPool(device, pool, nullptr);
        vkDestroyDevice(device, nullptr);
        vkDestroyInstance(instance, nullptr);
    }

    Buffer buffer(VkDeviceSize size) {
        Buffer b;
        b.size = size;
        VkBufferCreateInfo info{VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO};
        info.size = size;
        // One pool of buffers for every role a cluster build gives them (inputs, destinations,
        // scratch), as engines that sub-allocate do.
        info.usage = VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT | VK_BUFFER_USAGE_TRANSFER_SRC_BIT |
                     VK_BUFFER_USAGE_TRANSFER_DST_BIT | VK_BUFFER_USAGE_STORAGE_BUFFER_BIT |
                     VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR |
                     VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR;
        vk_ok(vkCreateBuffer(device, &info, nullptr, &b.buffer), "vkCreateBuffer");
        VkMemoryRequirements need;
        vkGetBufferMemoryRequirements(device, b.buffer, &need);
        VkMemoryAllocateFlagsInfo flags{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_FLAGS_INFO};
        flags.flags = VK_MEMORY_ALLOCATE_DEVICE_ADDRESS_BIT;
        VkMemoryAllocateInfo alloc{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO, &flags};
        alloc.allocationSize = need.size;
        alloc.memoryTypeIndex = host_visible_type(need.memoryTypeBits);
        vk_ok(vkAllocateMemory(device, &alloc, nullptr, &b.memory), "vkAllocateMemory");
        vk_ok(vkBindBufferMemory(device, b.buffer, b.memory, 0), "vkBindBufferMemory");
        VkBufferDeviceAddressInfo where{VK_STRUCTURE_TYPE_BUFFER_DEVICE_ADDRESS_INFO, nullptr,
                                        b.buffer};
        b.address = vkGetBufferDeviceAddress(device, &where);
        void* mapped = nullptr;
        vk_ok(vkMapMemory(device, b.memory, 0, VK_WHOLE_SIZE, 0, &mapped), "vkMapMemory");
        b.host = static_cast<unsigned char*>(mapped);
        std::memset(b.host, 0, size);
        buffers.push_back(b);
        return b;
    }

    VkCommandBuffer begin() {
        VkCommandBufferAllocateInfo info{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO};
        info.commandPool = pool;
        info.level = VK_COMMAND_BUFFER_LEVEL_PRIMARY;
        info.commandBufferCount = 1;
        VkCommandBuffer cb = VK_NULL_HANDLE;
        vk_ok(vkAllocateCommandBuffers(device, &info, &cb), "vkAllocateCommandBuffers");
        VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
        begin.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
        vk_ok(vkBeginCommandBuffer(cb, &begin), "vkBeginCommandBuffer");
        return cb;
    }

    VkFence fence() {
        VkFenceCreateInfo info{VK_STRUCTURE_TYPE_FENCE_CREATE_INFO};
        VkFence f = VK_NULL_HANDLE;
        vk_ok(vkCreateFence(device, &info, nullptr, &f), "vkCreateFence");
        return f;
    }

    // Ends `cb` and submits it alone (vkQueueSubmit2), signalling `done` when given.
    void submit(VkCommandBuffer cb, VkFence done = VK_NULL_HANDLE) {
        vk_ok(vkEndCommandBuffer(cb), "vkEndCommandBuffer");
        VkCommandBufferSubmitInfo command{VK_STRUCTURE_TYPE_COMMAND_BUFFER_SUBMIT_INFO};
        command.commandBuffer = cb;
        VkSubmitInfo2 submit{VK_STRUCTURE_TYPE_SUBMIT_INFO_2};
        submit.commandBufferInfoCount = 1;
        submit.pCommandBufferInfos = &command;
        vk_ok(vkQueueSubmit2(queue, 1, &submit, done), "vkQueueSubmit2");
    }

    void wait(VkFence done) {
        vk_ok(vkWaitForFences(device, 1, &done, VK_TRUE, UINT64_MAX), "vkWaitForFences");
        vkDestroyFence(device, done, nullptr);
    }

    void submit_and_wait(VkCommandBuffer cb) {
        VkFence done = fence();
        submit(cb, done);
        wait(done);
    }

private:
    uint32_t host_visible_type(uint32_t allowed) const {
        VkPhysicalDeviceMemoryProperties memory;
        vkGetPhysicalDeviceMemoryProperties(physical, &memory);
        const VkMemoryPropertyFlags want =
            VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT | VK_MEMORY_PROPERTY_HOST_COHERENT_BIT;
        for (uint32_t i = 0; i < memory.memoryTypeCount; ++i)
            if ((allowed & (1u << i)) && (memory.memoryTypes[i].propertyFlags & want) == want)
                return i;
        die("no host-visible coherent memory type");
    }
};

inline bool device_has_extension(VkPhysicalDevice physical, const char* name) {
    uint32_t count = 0;
    vkEnumerateDeviceExtensionProperties(physical, nullptr, &count, nullptr);
    std::vector<VkExtensionProperties> all(count);
    vkEnumerateDeviceExtensionProperties(physical, nullptr, &count, all.data());
    for (const VkExtensionProperties& e : all)
        if (std::strcmp(e.extensionName, name) == 0) return true;
    return false;
}

// Opens the first physical device with a compute queue and the cluster extension; exits with
// kUnsupported when there is none.
inline void open(Gpu& gpu, const char* application) {
    VkApplicationInfo app{VK_STRUCTURE_TYPE_APPLICATION_INFO};
    app.pApplicationName = application;
    app.pEngineName = "outside-engine";
    app.apiVersion = VK_API_VERSION_1_3;
    VkInstanceCreateInfo instance_info{VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO};
    instance_info.pApplicationInfo = &app;
    vk_ok(vkCreateInstance(&instance_info, nullptr, &gpu.instance), "vkCreateInstance");
    uint32_t count = 1;
    VkResult r = vkEnumeratePhysicalDevices(gpu.instance, &count, &gpu.physical);
    if ((r != VK_SUCCESS && r != VK_INCOMPLETE) || count == 0) unsupported("no physical device");
    VkPhysicalDeviceProperties props;
    vkGetPhysicalDeviceProperties(gpu.physical, &props);
    if (props.apiVersion < VK_API_VERSION_1_3) unsupported("Vulkan 1.3");
    if (!device_has_extension(gpu.physical, VK_NV_CLUSTER_ACCELERATION_STRUCTURE_EXTENSION_NAME))
        unsupported(VK_NV_CLUSTER_ACCELERATION_STRUCTURE_EXTENSION_NAME);

    uint32_t families = 0;
    vkGetPhysicalDeviceQueueFamilyProperties(gpu.physical, &families, nullptr);
    std::vector<VkQueueFamilyProperties> family(families);
    vkGetPhysicalDeviceQueueFamilyProperties(gpu.physical, &families, family.data());
    while (gpu.family < families && !(family[gpu.family].queueFlags & VK_QUEUE_COMPUTE_BIT))
        ++gpu.family;
    if (gpu.family == families) unsupported("a compute queue");

    const float priority = 1.0f;
    VkDeviceQueueCreateInfo queue_info{VK_STRUCTURE_TYPE_DEVICE_QUEUE_CREATE_INFO};
    queue_info.queueFamilyIndex = gpu.family;
    queue_info.queueCount = 1;
    queue_info.pQueuePriorities = &priority;
    VkPhysicalDeviceClusterAccelerationStructureFeaturesNV clusters{
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_CLUSTER_ACCELERATION_STRUCTURE_FEATURES_NV};
    clusters.clusterAccelerationStructure = VK_TRUE;
    VkPhysicalDeviceVulkan12Features v12{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_2_FEATURES,
                                         &clusters};
    v12.bufferDeviceAddress = VK_TRUE;
    v12.timelineSemaphore = VK_TRUE;
    VkPhysicalDeviceVulkan13Features v13{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_3_FEATURES,
                                         &v12};
    v13.synchronization2 = VK_TRUE;
    // The cluster extension builds on VK_KHR_acceleration_structure; a driver whose cluster
    // support is served by a layer may lack it, and the programs use nothing of it but the
    // buffer usage bits.
    std::vector<const char*> extensions{VK_NV_CLUSTER_ACCELERATION_STRUCTURE_EXTENSION_NAME};
    VkPhysicalDeviceAccelerationStructureFeaturesKHR structures{
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_ACCELERATION_STRUCTURE_FEATURES_KHR};
    if (device_has_extension(gpu.physical, VK_KHR_ACCELERATION_STRUCTURE_EXTENSION_NAME)) {
        extensions.push_back(VK_KHR_ACCELERATION_STRUCTURE_EXTENSION_NAME);
        extensions.push_back(VK_KHR_DEFERRED_HOST_OPERATIONS_EXTENSION_NAME);
        structures.accelerationStructure = VK_TRUE;
        clusters.pNext = &structures;
        gpu.khr_structures = true;
    }
    VkDeviceCreateInfo device_info{VK_STRUCTURE_TYPE_DEVICE_CREATE_INFO, &v13};
    device_info.queueCreateInfoCount = 1;
    device_info.pQueueCreateInfos = &queue_info;
    device_info.enabledExtensionCount = uint32_t(extensions.size());
    device_info.ppEnabledExtensionNames = extensions.data();
    vk_ok(vkCreateDevice(gpu.physical, &device_info, nullptr, &gpu.device), "vkCreateDevice");
    vkGetDeviceQueue(gpu.device, gpu.family, 0, &gpu.queue);

    VkCommandPoolCreateInfo pool_info{VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO};
    pool_info.queueFamilyIndex = gpu.family;
    vk_ok(vkCreateCommandPool(gpu.device, &pool_info, nullptr, &gpu.pool), "vkCreateCommandPool");

    gpu.cluster_props.sType =
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_CLUSTER_ACCELERATION_STRUCTURE_PROPERTIES_NV;
    VkPhysicalDeviceProperties2 props2{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2,
                                       &gpu.cluster_props};
    vkGetPhysicalDeviceProperties2(gpu.physical, &props2);
    gpu.cmd_build_clusters = reinterpret_cast<PFN_vkCmdBuildClusterAccelerationStructureIndirectNV>(
        vkGetDeviceProcAddr(gpu.device, "vkCmdBuildClusterAccelerationStructureIndirectNV"));
    gpu.get_cluster_sizes = reinterpret_cast<PFN_vkGetClusterAccelerationStructureBuildSizesNV>(
        vkGetDeviceProcAddr(gpu.device, "vkGetClusterAccelerationStructureBuildSizesNV"));
    if (!gpu.cmd_build_clusters || !gpu.get_cluster_sizes) unsupported("the cluster entry points");
}

// Tells the test where a range the bug touches lies: one line "NAME 0xADDRESS SIZE".
inline void print_range(const char* name, VkDeviceAddress address, VkDeviceSize size) {
    std::printf("%s 0x%llx %llu\n", name, static_cast<unsigned long long>(address),
                static_cast<unsigned long long>(size));
}

inline VkDeviceSize align_up(VkDeviceSize value, VkDeviceSize alignment) {
    return alignment ? (value + alignment - 1) / alignment * alignment : value;
}

// Geometry an engine would stream in: `count` clusters, each one quad (4 float3 vertices,
// 2 triangles with 32-bit indices), side by side along x.
struct Quads {
    Buffer vertices, indices;
    uint32_t count = 0;
};

inline Quads make_quads(Gpu& gpu, uint32_t count) {
    Quads q;
    q.count = count;
    q.vertices = gpu.buffer(VkDeviceSize(count) * 4 * 3 * sizeof(float));
    q.indices = gpu.buffer(VkDeviceSize(count) * 6 * sizeof(uint32_t));
    auto* v = reinterpret_cast<float*>(q.vertices.host);
    auto* i = reinterpret_cast<uint32_t*>(q.indices.host);
    for (uint32_t c = 0; c < count; ++c) {
        const float corners[4][3] = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}};
        for (int k = 0; k < 4; ++k) {
            v[c * 12 + k * 3 + 0] = corners[k][0] + 2.0f * float(c);
            v[c * 12 + k * 3 + 1] = corners[k][1];
            v[c * 12 + k * 3 + 2] = corners[k][2];
        }
        const uint32_t local[6] = {0, 1, 2, 0, 2, 3};
        for (int k = 0; k < 6; ++k) i[c * 6 + k] = local[k];
    }
    return q;
}

// The src info of quad `c` (its own 4 vertices, indices local to them).
inline VkClusterAccelerationStructureBuildTriangleClusterInfoNV quad_info(const Quads& q,
                                                                          uint32_t c) {
    VkClusterAccelerationStructureBuildTriangleClusterInfoNV info{};
    info.clusterID = c;
    info.triangleCount = 2;
    info.vertexCount = 4;
    info.indexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_32BIT_NV;
    info.indexBufferStride = sizeof(uint32_t);
    info.vertexBufferStride = 3 * sizeof(float);
    info.indexBuffer = q.indices.address + VkDeviceSize(c) * 6 * sizeof(uint32_t);
    info.vertexBuffer = q.vertices.address + VkDeviceSize(c) * 4 * 3 * sizeof(float);
    return info;
}

// One implicit-destination build of triangle clusters: the command info and the buffers it
// names. The src infos are written on the host unless the caller writes them otherwise.
struct ClasBuild {
    VkClusterAccelerationStructureTriangleClusterInputNV limits{};
    VkClusterAccelerationStructureCommandsInfoNV info{};
    Buffer infos, count, objects, addresses, scratch;
};

inline VkAccelerationStructureBuildSizesInfoKHR sizes_of(
    Gpu& gpu, const VkClusterAccelerationStructureInputInfoNV& in) {
    VkAccelerationStructureBuildSizesInfoKHR sizes{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_SIZES_INFO_KHR};
    gpu.get_cluster_sizes(gpu.device, &in, &sizes);
    if (sizes.accelerationStructureSize == 0) die("the driver answered no size for the input");
    return sizes;
}

// `build` must not move after this returns: its info points at its own limits.
inline void prepare_clas_build(Gpu& gpu, const Quads& q, ClasBuild& build) {
    build.limits = {VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_TRIANGLE_CLUSTER_INPUT_NV};
    build.limits.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    build.limits.maxGeometryIndexValue = 0;
    build.limits.maxClusterUniqueGeometryCount = 1;
    build.limits.maxClusterTriangleCount = 2;
    build.limits.maxClusterVertexCount = 4;
    build.limits.maxTotalTriangleCount = 2 * q.count;
    build.limits.maxTotalVertexCount = 4 * q.count;
    VkClusterAccelerationStructureCommandsInfoNV& info = build.info;
    info = {VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV};
    info.input.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_INPUT_INFO_NV;
    info.input.maxAccelerationStructureCount = q.count;
    info.input.opType = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV;
    info.input.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
    info.input.opInput.pTriangleClusters = &build.limits;
    const VkAccelerationStructureBuildSizesInfoKHR sizes = sizes_of(gpu, info.input);
    const uint32_t info_size = sizeof(VkClusterAccelerationStructureBuildTriangleClusterInfoNV);
    build.infos = gpu.buffer(VkDeviceSize(info_size) * q.count);
    build.count = gpu.buffer(sizeof(uint32_t));
    build.objects = gpu.buffer(sizes.accelerationStructureSize);
    build.addresses = gpu.buffer(sizeof(VkDeviceAddress) * q.count);
    build.scratch = gpu.buffer(sizes.buildScratchSize);
    for (uint32_t c = 0; c < q.count; ++c) {
        const auto one = quad_info(q, c);
        std::memcpy(build.infos.host + VkDeviceSize(c) * info_size, &one, info_size);
    }
    std::memcpy(build.count.host, &q.count, sizeof q.count);
    info.dstImplicitData = build.objects.address;
    info.scratchData = build.scratch.address;
    info.dstAddressesArray = {build.addresses.address, sizeof(VkDeviceAddress),
                              sizeof(VkDeviceAddress) * q.count};
    info.srcInfosArray = {build.infos.address, info_size, VkDeviceSize(info_size) * q.count};
    info.srcInfosCount = build.count.address;
}

// One bottom level over every CLAS whose address `clas` writes to its dstAddressesArray.
struct BlasBuild {
    VkClusterAccelerationStructureClustersBottomLevelInputNV limits{};
    VkClusterAccelerationStructureCommandsInfoNV info{};
    Buffer infos, count, objects, addresses, scratch;
};

inline void prepare_blas_build(Gpu& gpu, const ClasBuild& clas, uint32_t clusters,
                               BlasBuild& build) {
    build.limits = {
        VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_CLUSTERS_BOTTOM_LEVEL_INPUT_NV};
    build.limits.maxTotalClusterCount = clusters;
    build.limits.maxClusterCountPerAccelerationStructure = clusters;
    VkClusterAccelerationStructureCommandsInfoNV& info = build.info;
    info = {VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV};
    info.input.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_INPUT_INFO_NV;
    info.input.maxAccelerationStructureCount = 1;
    info.input.opType = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV;
    info.input.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
    info.input.opInput.pClustersBottomLevel = &build.limits;
    const VkAccelerationStructureBuildSizesInfoKHR sizes = sizes_of(gpu, info.input);
    build.infos = gpu.buffer(sizeof(VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV));
    build.count = gpu.buffer(sizeof(uint32_t));
    build.objects = gpu.buffer(sizes.accelerationStructureSize);
    build.addresses = gpu.buffer(sizeof(VkDeviceAddress));
    build.scratch = gpu.buffer(sizes.buildScratchSize);
    VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV one{};
    one.clusterReferencesCount = clusters;
    one.clusterReferencesStride = sizeof(VkDeviceAddress);
    one.clusterReferences = clas.addresses.address;
    std::memcpy(build.infos.host, &one, sizeof one);
    const uint32_t blas_count = 1;
    std::memcpy(build.count.host, &blas_count, sizeof blas_count);
    info.dstImplicitData = build.objects.address;
    info.scratchData = build.scratch.address;
    info.dstAddressesArray = {build.addresses.address, sizeof(VkDeviceAddress),
                              sizeof(VkDeviceAddress)};
    info.srcInfosArray = {build.infos.address, sizeof one, sizeof one};
    info.srcInfosCount = build.count.address;
}

// A VkMemoryBarrier2 in a vkCmdPipelineBarrier2 of its own.
inline void memory_barrier(VkCommandBuffer cb, VkPipelineStageFlags2 src_stage,
                           VkAccessFlags2 src_access, VkPipelineStageFlags2 dst_stage,
                           VkAccessFlags2 dst_access) {
    VkMemoryBarrier2 barrier{VK_STRUCTURE_TYPE_MEMORY_BARRIER_2};
    barrier.srcStageMask = src_stage;
    barrier.srcAccessMask = src_access;
    barrier.dstStageMask = dst_stage;
    barrier.dstAccessMask = dst_access;
    VkDependencyInfo dependency{VK_STRUCTURE_TYPE_DEPENDENCY_INFO};
    dependency.memoryBarrierCount = 1;
    dependency.pMemoryBarriers = &barrier;
    vkCmdPipelineBarrier2(cb, &dependency);
}

// A VkBufferMemoryBarrier2 over [offset, offset + size) of `buffer`, alone in its
// vkCmdPipelineBarrier2.
inline void buffer_barrier(VkCommandBuffer cb, VkBuffer buffer, VkDeviceSize offset,
                           VkDeviceSize size, VkPipelineStageFlags2 src_stage,
                           VkAccessFlags2 src_access, VkPipelineStageFlags2 dst_stage,
                           VkAccessFlags2 dst_access) {
    VkBufferMemoryBarrier2 barrier{VK_STRUCTURE_TYPE_BUFFER_MEMORY_BARRIER_2};
    barrier.srcStageMask = src_stage;
    barrier.srcAccessMask = src_access;
    barrier.dstStageMask = dst_stage;
    barrier.dstAccessMask = dst_access;
    barrier.srcQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
    barrier.dstQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
    barrier.buffer = buffer;
    barrier.offset = offset;
    barrier.size = size;
    VkDependencyInfo dependency{VK_STRUCTURE_TYPE_DEPENDENCY_INFO};
    dependency.bufferMemoryBarrierCount = 1;
    dependency.pBufferMemoryBarriers = &barrier;
    vkCmdPipelineBarrier2(cb, &dependency);
}

// The build barrier engines put between two cluster steps that hand objects on.
inline void build_to_build_barrier(VkCommandBuffer cb) {
    memory_barrier(cb, VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                   VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR,
                   VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                   VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR);
}

// Turns `build` into an explicit-destination build: every object in a slot of its own, as
// large as the driver's answer for one, at addresses the host chose (so later infos can name
// them without reading anything back). Returns the slot size.
inline VkDeviceSize place_explicitly(Gpu& gpu, VkClusterAccelerationStructureCommandsInfoNV& info,
                                     Buffer& addresses, uint32_t count, VkDeviceSize alignment) {
    info.input.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV;
    const VkDeviceSize one =
        align_up(sizes_of(gpu, info.input).accelerationStructureSize, alignment);
    info.dstImplicitData = 0;
    Buffer place = gpu.buffer(one * (count + 1));
    const VkDeviceAddress base = align_up(place.address, alignment);
    auto* destinations = reinterpret_cast<VkDeviceAddress*>(addresses.host);
    for (uint32_t c = 0; c < count; ++c) destinations[c] = base + c * one;
    return one;
}

}  // namespace bug_programs
