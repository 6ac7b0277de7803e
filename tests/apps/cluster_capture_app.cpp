// SPDX-License-Identifier: Apache-2.0
// A headless compute-only Vulkan program that uses VK_NV_cluster_acceleration_structure through
// the loader, for the capture layer's tests. Modes:
//   limits OUT.json        queries the extension, its feature and properties, and build sizes
//   exactness OUT.json     one command buffer writes a build's inputs with transfer commands,
//                          builds, then overwrites them; OUT.json lists the bytes the builds
//                          must have read (and the memory's final state, which differs)
//   dispatch OUT.json      a compute dispatch with storage buffers bound (one dynamic)
//   resubmit N             one command buffer submitted N times, the host changing the count
//   pause-cost N           N builds in one submission; prints the time per build
//   host-rewrite WHEN      one build of a cluster from src infos in mapped memory; the host
//                          rewrites the infos after vkQueueSubmit, WHEN = before-wait (a race:
//                          the build may read either bytes) or after-wait (the fence wait
//                          ordered the build first), then submits once more and waits;
//                          before-run: the build waits for a timeline value the host signals
//                          after the rewrite and one more (empty) submission
//   host-rewrite WHEN PLACE  the same with the infos 8 KiB into a 32 KiB buffer, on a page the
//                          layer's page guard can protect (capture/README.md, "Host writes"):
//                          PLACE = paged (the rewrite as above), neighbour (the host writes the
//                          infos' page beside them instead), thread (another thread rewrites),
//                          app-handler (the app takes SIGSEGV for a page of its own after the
//                          first submission, and faults on it before the second's rewrite; exit
//                          4 unless its handler saw that one fault), layer-writes (no rewrite; the
//                          served build writes its implicit data on the infos' page)
//   serve OUT.json         served_scene.h: triangle clusters, then a bottom level over the
//                          addresses the first build wrote, in one command buffer; OUT.json
//                          holds every buffer's address and what the builds wrote. Exit 3
//                          when the device does not offer the extension.
//   serve-frames OUT.json  the same scene over three frames marked with VkFrameBoundaryEXT (no
//                          presents): the clusters built in frame 0, built again over the same
//                          memory in frame 1, the bottom level over them in frame 2; OUT.json
//                          holds the bottom level's bytes and its address. Exit 3 as `serve`.
//   serve-frames-gated OUT.json  the same, but frame 1's build waits for a timeline value the
//                          host signals only after submitting frame 2 (its capture comes after
//                          frame 2's vkQueueSubmit returned)
#include "cluster_test_device.h"
#include "served_scene.h"

#include <clastrace/vk_cluster_abi.h>
#include <clastrace/vk_frame_boundary_abi.h>

#include <nlohmann/json.hpp>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <atomic>
#include <csignal>
#include <fstream>
#include <map>
#include <string>
#include <thread>
#include <vector>

#include <sys/mman.h>

namespace {

using namespace clastrace::testapp;

// Everything it made is destroyed when a mode returns.
struct Context : ClusterTestDevice {
    ~Context() { destroy(); }
};

void transferToBuildBarrier(VkCommandBuffer cb) {
    VkMemoryBarrier barrier{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr, VK_ACCESS_TRANSFER_WRITE_BIT,
                            VK_ACCESS_MEMORY_READ_BIT};
    vkCmdPipelineBarrier(cb, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT, 0,
                         1, &barrier, 0, nullptr, 0, nullptr);
}

void buildToTransferBarrier(VkCommandBuffer cb) {
    VkMemoryBarrier barrier{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr,
                            VK_ACCESS_MEMORY_READ_BIT | VK_ACCESS_MEMORY_WRITE_BIT,
                            VK_ACCESS_TRANSFER_WRITE_BIT};
    vkCmdPipelineBarrier(cb, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT, VK_PIPELINE_STAGE_TRANSFER_BIT, 0,
                         1, &barrier, 0, nullptr, 0, nullptr);
}

int limits(const char* outPath) {
    Context c;
    c.createInstance();
    nlohmann::json out;
    out["extensionListed"] = c.hasClusterExtension();
    VkPhysicalDeviceClusterAccelerationStructureFeaturesNV features{
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_CLUSTER_ACCELERATION_STRUCTURE_FEATURES_NV, nullptr,
        VK_FALSE};
    VkPhysicalDeviceFeatures2 features2{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_FEATURES_2,
                                        &features,
                                        {}};
    vkGetPhysicalDeviceFeatures2(c.physicalDevice, &features2);
    out["clusterAccelerationStructure"] = features.clusterAccelerationStructure == VK_TRUE;
    VkPhysicalDeviceClusterAccelerationStructurePropertiesNV p{};
    p.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_CLUSTER_ACCELERATION_STRUCTURE_PROPERTIES_NV;
    VkPhysicalDeviceProperties2 properties2{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2, &p, {}};
    vkGetPhysicalDeviceProperties2(c.physicalDevice, &properties2);
    out["deviceName"] = properties2.properties.deviceName;
    out["properties"] = {{"maxVerticesPerCluster", p.maxVerticesPerCluster},
                         {"maxTrianglesPerCluster", p.maxTrianglesPerCluster},
                         {"clusterScratchByteAlignment", p.clusterScratchByteAlignment},
                         {"clusterByteAlignment", p.clusterByteAlignment},
                         {"clusterTemplateByteAlignment", p.clusterTemplateByteAlignment},
                         {"clusterBottomLevelByteAlignment", p.clusterBottomLevelByteAlignment},
                         {"clusterTemplateBoundsByteAlignment",
                          p.clusterTemplateBoundsByteAlignment},
                         {"maxClusterGeometryIndex", p.maxClusterGeometryIndex}};
    if (out["extensionListed"]) {
        c.createDevice();
        VkClusterAccelerationStructureTriangleClusterInputNV tri{};
        tri.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_TRIANGLE_CLUSTER_INPUT_NV;
        tri.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
        tri.maxClusterTriangleCount = 128;
        tri.maxClusterVertexCount = 128;
        tri.maxTotalTriangleCount = 1024;
        tri.maxTotalVertexCount = 1024;
        VkClusterAccelerationStructureInputInfoNV input{};
        input.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_INPUT_INFO_NV;
        input.maxAccelerationStructureCount = 8;
        input.opType = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV;
        input.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
        input.opInput.pTriangleClusters = &tri;
        VkAccelerationStructureBuildSizesInfoKHR sizes{
            VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_SIZES_INFO_KHR, nullptr, 0, 0, 0};
        c.getBuildSizes(c.device, &input, &sizes);
        out["buildSizes"] = {{"accelerationStructureSize", sizes.accelerationStructureSize},
                             {"buildScratchSize", sizes.buildScratchSize},
                             {"updateScratchSize", sizes.updateScratchSize}};
    }
    std::ofstream(outPath) << out.dump(1);
    return 0;
}

// Layout of the exactness scene: two triangle clusters (srcInfosCount says 2 of at most 3),
// entries 80 bytes apart, then one bottom-level build over two cluster references.
constexpr VkDeviceSize kInfoStride = 80;
// Cluster 0: a quad, 4 vertices packed (stride 0), 16-bit indices, per-triangle geometry words.
// Cluster 1: one triangle, 3 vertices 16 bytes apart, 32-bit indices 8 bytes apart.
constexpr float kQuad[4][3] = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}};
constexpr float kTri[3][4] = {{2, 0, 0, -1}, {3, 0, 0, -1}, {2, 1, 0.5f, -1}};  // 4th: padding
constexpr uint16_t kQuadIndices[6] = {0, 1, 2, 0, 2, 3};
constexpr uint32_t kTriIndices[6] = {0, 0xAAAAAAAA, 1, 0xAAAAAAAA, 2, 0xAAAAAAAA};  // stride 8
constexpr uint32_t kGeometryWords[2] = {(1u << 29) | 5u, (4u << 29) | 6u};
constexpr VkDeviceAddress kClusterRefs[2] = {0x1000, 0x2000};
constexpr VkDeviceSize kQuadOffset = 0, kTriOffset = 64, kQuadIndexOffset = 0, kTriIndexOffset = 64;

// The exactness scene's buffers and the src infos its builds read.
struct ExactnessScene {
    Buffer staging, infos, counts, vertices, indices, geometry, references, dstAddresses, dstSizes,
        implicitData, scratch;
    VkClusterAccelerationStructureBuildTriangleClusterInfoNV cluster[2]{};
    VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV blas{};
    uint8_t infoBytes[2 * kInfoStride];

    explicit ExactnessScene(Context& c)
        : staging(c.makeBuffer(4096, 0, 0xEE)),
          infos(c.makeBuffer(4096, 0, 0xEE)),
          counts(c.makeBuffer(256, 0, 0xEE)),
          vertices(c.makeBuffer(1024, 0, 0xEE)),
          indices(c.makeBuffer(256, 0, 0xEE)),
          geometry(c.makeBuffer(256, 0, 0xEE)),
          references(c.makeBuffer(256, 0, 0xEE)),
          dstAddresses(c.makeBuffer(256, 0, 0xEE)),
          dstSizes(c.makeBuffer(256, 0, 0xEE)),
          implicitData(c.makeBuffer(1 << 16, 0, 0)),
          scratch(c.makeBuffer(1 << 16, 0, 0)) {
        cluster[0].clusterID = 100;
        cluster[0].triangleCount = 2;
        cluster[0].vertexCount = 4;
        cluster[0].indexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_16BIT_NV;
        cluster[0].indexBuffer = indices.address + kQuadIndexOffset;
        cluster[0].vertexBuffer = vertices.address + kQuadOffset;
        cluster[0].geometryIndexAndFlagsBuffer = geometry.address;
        cluster[1].clusterID = 101;
        cluster[1].triangleCount = 1;
        cluster[1].vertexCount = 3;
        cluster[1].indexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_32BIT_NV;
        cluster[1].indexBufferStride = 8;
        cluster[1].vertexBufferStride = 16;
        cluster[1].indexBuffer = indices.address + kTriIndexOffset;
        cluster[1].vertexBuffer = vertices.address + kTriOffset;
        cluster[1].baseGeometryIndexAndGeometryFlags.geometryIndex = 9;
        std::memset(infoBytes, 0xCD, sizeof infoBytes);  // the gap between entries: not read
        std::memcpy(infoBytes, &cluster[0], sizeof cluster[0]);
        std::memcpy(infoBytes + kInfoStride, &cluster[1], sizeof cluster[1]);
        blas.clusterReferencesCount = 2;
        blas.clusterReferences = references.address;
    }
};

// Transfer commands write every input the builds read; the entries reach srcInfosArray by copy.
void recordInputs(VkCommandBuffer cb, ExactnessScene& s) {
    vkCmdFillBuffer(cb, s.counts.buffer, 0, 4, 2);  // srcInfosCount of the cluster build: 2
    vkCmdFillBuffer(cb, s.counts.buffer, 4, 4, 1);  // srcInfosCount of the bottom-level build: 1
    vkCmdUpdateBuffer(cb, s.staging.buffer, 0, sizeof s.infoBytes, s.infoBytes);
    VkBufferCopy copy{0, 0, sizeof s.infoBytes};
    transferToBuildBarrier(cb);
    vkCmdCopyBuffer(cb, s.staging.buffer, s.infos.buffer, 1, &copy);
    vkCmdUpdateBuffer(cb, s.infos.buffer, 1024, sizeof s.blas, &s.blas);
    vkCmdUpdateBuffer(cb, s.vertices.buffer, kQuadOffset, sizeof kQuad, kQuad);
    vkCmdUpdateBuffer(cb, s.vertices.buffer, kTriOffset, sizeof kTri, kTri);
    vkCmdUpdateBuffer(cb, s.indices.buffer, kQuadIndexOffset, sizeof kQuadIndices, kQuadIndices);
    vkCmdUpdateBuffer(cb, s.indices.buffer, kTriIndexOffset, sizeof kTriIndices, kTriIndices);
    vkCmdUpdateBuffer(cb, s.geometry.buffer, 0, sizeof kGeometryWords, kGeometryWords);
    vkCmdUpdateBuffer(cb, s.references.buffer, 0, sizeof kClusterRefs, kClusterRefs);
    vkCmdFillBuffer(cb, s.dstSizes.buffer, 0, 256, 0x77777777);  // what the "after" pause sees
    transferToBuildBarrier(cb);
}

void recordClusterBuild(Context& c, VkCommandBuffer cb, const ExactnessScene& s) {
    VkClusterAccelerationStructureTriangleClusterInputNV triangleInput{};
    triangleInput.sType =
        VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_TRIANGLE_CLUSTER_INPUT_NV;
    triangleInput.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    triangleInput.maxGeometryIndexValue = 16;
    triangleInput.maxClusterUniqueGeometryCount = 2;
    triangleInput.maxClusterTriangleCount = 2;
    triangleInput.maxClusterVertexCount = 4;
    triangleInput.maxTotalTriangleCount = 3;
    triangleInput.maxTotalVertexCount = 7;
    VkClusterAccelerationStructureCommandsInfoNV build{};
    build.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV;
    build.input.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_INPUT_INFO_NV;
    build.input.maxAccelerationStructureCount = 3;
    build.input.opType = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV;
    build.input.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
    build.input.opInput.pTriangleClusters = &triangleInput;
    build.dstImplicitData = s.implicitData.address;
    build.scratchData = s.scratch.address;
    build.dstAddressesArray = {s.dstAddresses.address, 8, 24};
    build.dstSizesArray = {s.dstSizes.address, 4, 12};
    build.srcInfosArray = {s.infos.address, kInfoStride, 3 * kInfoStride};
    build.srcInfosCount = s.counts.address;
    c.cmdBuildClusters(cb, &build);
}

void recordBottomLevelBuild(Context& c, VkCommandBuffer cb, const ExactnessScene& s) {
    VkClusterAccelerationStructureClustersBottomLevelInputNV blasInput{};
    blasInput.sType =
        VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_CLUSTERS_BOTTOM_LEVEL_INPUT_NV;
    blasInput.maxTotalClusterCount = 2;
    blasInput.maxClusterCountPerAccelerationStructure = 2;
    VkClusterAccelerationStructureCommandsInfoNV blasBuild{};
    blasBuild.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV;
    blasBuild.input.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_INPUT_INFO_NV;
    blasBuild.input.maxAccelerationStructureCount = 1;
    blasBuild.input.opType =
        VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV;
    blasBuild.input.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
    blasBuild.input.opInput.pClustersBottomLevel = &blasInput;
    blasBuild.dstImplicitData = s.implicitData.address + 32768;
    blasBuild.scratchData = s.scratch.address + 32768;
    blasBuild.srcInfosArray = {s.infos.address + 1024, 0, sizeof s.blas};
    blasBuild.srcInfosCount = s.counts.address + 4;
    c.cmdBuildClusters(cb, &blasBuild);
}

// Overwrite everything the builds read: a capture taken at any other moment shows these.
void recordOverwrites(VkCommandBuffer cb, const ExactnessScene& s) {
    buildToTransferBarrier(cb);
    vkCmdFillBuffer(cb, s.counts.buffer, 0, 8, 7);
    vkCmdFillBuffer(cb, s.vertices.buffer, 0, 1024, 0x3F800000);
    vkCmdFillBuffer(cb, s.indices.buffer, 0, 256, 0x01010101);
    vkCmdFillBuffer(cb, s.dstSizes.buffer, 0, 256, 0x99999999);
}

// The bytes each build must have read, and the memory's final state (which differs).
nlohmann::json exactnessJson(const ExactnessScene& s) {
    auto range = [](VkDeviceAddress address, const void* data, size_t size) {
        return nlohmann::json{{"address", address}, {"bytes", hex(data, size)}};
    };
    const uint32_t two = 2, one = 1;
    const auto& cluster = s.cluster;
    nlohmann::json out;
    out["clusterBuild"] = {
        {"srcInfosCount", range(s.counts.address, &two, 4)},
        {"srcInfos",
         {range(s.infos.address, &cluster[0], 64),
          range(s.infos.address + kInfoStride, &cluster[1], 64)}},
        {"indexBuffer",
         {range(cluster[0].indexBuffer, kQuadIndices, sizeof kQuadIndices),
          range(cluster[1].indexBuffer, &kTriIndices[0], 4),
          range(cluster[1].indexBuffer + 8, &kTriIndices[2], 4),
          range(cluster[1].indexBuffer + 16, &kTriIndices[4], 4)}},
        {"vertexBuffer",
         {range(cluster[0].vertexBuffer, kQuad, sizeof kQuad),
          range(cluster[1].vertexBuffer, kTri[0], 12),
          range(cluster[1].vertexBuffer + 16, kTri[1], 12),
          range(cluster[1].vertexBuffer + 32, kTri[2], 12)}},
        {"geometryIndexAndFlagsBuffer",
         {range(s.geometry.address, kGeometryWords, sizeof kGeometryWords)}},
        {"dstSizesAfter", range(s.dstSizes.address, std::vector<uint8_t>(8, 0x77).data(), 8)},
    };
    out["bottomLevelBuild"] = {
        {"srcInfosCount", range(s.counts.address + 4, &one, 4)},
        {"srcInfos", {range(s.infos.address + 1024, &s.blas, sizeof s.blas)}},
        {"clusterReferences", {range(s.references.address, kClusterRefs, sizeof kClusterRefs)}},
    };
    out["finalMemory"] = {{"srcInfosCount", range(s.counts.address, s.counts.mapped, 4)},
                          {"vertexBuffer",
                           range(s.vertices.address, s.vertices.mapped, sizeof kQuad)},
                          {"dstSizes", range(s.dstSizes.address, s.dstSizes.mapped, 8)}};
    return out;
}

int exactness(const char* outPath) {
    Context c;
    c.createInstance();
    c.createDevice();
    ExactnessScene s(c);
    VkCommandBuffer cb = c.beginCommands();
    recordInputs(cb, s);
    recordClusterBuild(c, cb, s);
    recordBottomLevelBuild(c, cb, s);
    recordOverwrites(cb, s);
    c.submitAndWait(cb);
    std::ofstream(outPath) << exactnessJson(s).dump(1);
    return 0;
}

// One command buffer submitted `times` times; before each submission the host writes the
// build's count (1, 2, 3, 1, ...) into mapped memory. Each execution must be captured with
// its own count, and the layer's events must be ready again for the next submission.
int resubmit(int times) {
    Context c;
    c.createInstance();
    c.createDevice();
    Buffer counts = c.makeBuffer(256, 0, 0);
    Buffer infos = c.makeBuffer(1024, 0, 0);
    Buffer vertices = c.makeBuffer(256, 0, 0);
    Buffer indices = c.makeBuffer(256, 0, 0);
    VkClusterAccelerationStructureBuildTriangleClusterInfoNV cluster{};
    cluster.triangleCount = 1;
    cluster.vertexCount = 3;
    cluster.indexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_32BIT_NV;
    cluster.indexBuffer = indices.address;
    cluster.vertexBuffer = vertices.address;
    for (int i = 0; i < 3; ++i) {
        cluster.clusterID = 10 + i;
        std::memcpy(infos.mapped + i * sizeof cluster, &cluster, sizeof cluster);
    }
    VkClusterAccelerationStructureTriangleClusterInputNV triangleInput{};
    triangleInput.sType =
        VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_TRIANGLE_CLUSTER_INPUT_NV;
    triangleInput.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    VkClusterAccelerationStructureCommandsInfoNV build{};
    build.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV;
    build.input.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_INPUT_INFO_NV;
    build.input.maxAccelerationStructureCount = 3;
    build.input.opType = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV;
    build.input.opInput.pTriangleClusters = &triangleInput;
    build.srcInfosArray = {infos.address, 0, 3 * sizeof cluster};
    build.srcInfosCount = counts.address;

    VkCommandBufferAllocateInfo allocInfo{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO, nullptr,
                                          c.pool, VK_COMMAND_BUFFER_LEVEL_PRIMARY, 1};
    VkCommandBuffer cb;
    CHECK(vkAllocateCommandBuffers(c.device, &allocInfo, &cb));
    VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO, nullptr, 0,
                                   nullptr};
    CHECK(vkBeginCommandBuffer(cb, &begin));
    c.cmdBuildClusters(cb, &build);
    CHECK(vkEndCommandBuffer(cb));
    VkFenceCreateInfo fenceInfo{VK_STRUCTURE_TYPE_FENCE_CREATE_INFO, nullptr, 0};
    VkFence fence;
    CHECK(vkCreateFence(c.device, &fenceInfo, nullptr, &fence));
    for (int i = 0; i < times; ++i) {
        const uint32_t count = uint32_t(i % 3) + 1;
        std::memcpy(counts.mapped, &count, 4);
        VkSubmitInfo submit{};
        submit.sType = VK_STRUCTURE_TYPE_SUBMIT_INFO;
        submit.commandBufferCount = 1;
        submit.pCommandBuffers = &cb;
        CHECK(vkQueueSubmit(c.queue, 1, &submit, fence));
        CHECK(vkWaitForFences(c.device, 1, &fence, VK_TRUE, 30ull * 1000 * 1000 * 1000));
        CHECK(vkResetFences(c.device, 1, &fence));
    }
    vkDestroyFence(c.device, fence, nullptr);
    return 0;
}

// The host rewrites the src infos a submitted build reads, before or after the fence wait that
// orders the build (capture/README.md, "Host writes"). A correct program apart from that one
// rewrite: limits that hold the cluster, sizes from the driver's query, the usages the build
// needs, destinations and scratch of their own.
enum class Rewrite { kBeforeWait, kAfterWait, kBeforeRun };
enum class Placement { kOwnMemory, kPaged, kNeighbour, kThread, kAppHandler, kLayerWrites };

// The application's own guard page and its SIGSEGV handler (Placement::kAppHandler).
uint8_t* appGuardPage = nullptr;
std::atomic<int> appFaults{0};

void appFaultHandler(int, siginfo_t* info, void*) {
    auto* at = static_cast<uint8_t*>(info->si_addr);
    if (at < appGuardPage || at >= appGuardPage + 4096) std::abort();
    mprotect(appGuardPage, 4096, PROT_READ | PROT_WRITE);
    ++appFaults;
}

void takeSigsegv() {
    appGuardPage =
        static_cast<uint8_t*>(mmap(nullptr, 4096, PROT_NONE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0));
    if (appGuardPage == MAP_FAILED) fail("mmap");
    struct sigaction action {};
    action.sa_sigaction = appFaultHandler;
    action.sa_flags = SA_SIGINFO;
    sigemptyset(&action.sa_mask);
    if (sigaction(SIGSEGV, &action, nullptr) != 0) fail("sigaction");
}

// One triangle cluster built from infos the host rewrites around the submission (hostRewrite):
// its buffers, the infos' host pointer and the build's commands info.
struct RewriteScene {
    VkClusterAccelerationStructureTriangleClusterInputNV triangleInput{};
    VkClusterAccelerationStructureCommandsInfoNV build{};
    VkClusterAccelerationStructureBuildTriangleClusterInfoNV cluster{};
    Buffer counts, infos, vertices, indices, implicitData, scratch, dstAddresses, dstSizes;
    uint8_t* infosHost = nullptr;
};

void describeOneTriangleBuild(RewriteScene& s) {
    VkClusterAccelerationStructureTriangleClusterInputNV& in = s.triangleInput;
    in.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_TRIANGLE_CLUSTER_INPUT_NV;
    in.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    in.maxGeometryIndexValue = 0;
    in.maxClusterUniqueGeometryCount = 1;
    in.maxClusterTriangleCount = 1;
    in.maxClusterVertexCount = 3;
    in.maxTotalTriangleCount = 1;
    in.maxTotalVertexCount = 3;
    VkClusterAccelerationStructureCommandsInfoNV& build = s.build;
    build.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV;
    build.input.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_INPUT_INFO_NV;
    build.input.maxAccelerationStructureCount = 1;
    build.input.opType = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV;
    build.input.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
    build.input.opInput.pTriangleClusters = &in;
}

void makeRewriteScene(Context& c, Placement place, RewriteScene& s) {
    describeOneTriangleBuild(s);
    VkAccelerationStructureBuildSizesInfoKHR sizes{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_SIZES_INFO_KHR, nullptr, 0, 0, 0};
    c.getBuildSizes(c.device, &s.build.input, &sizes);
    if (!sizes.accelerationStructureSize || !sizes.buildScratchSize) fail("build sizes of 0");

    const VkBufferUsageFlags input =
        VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR;
    const VkBufferUsageFlags storage = VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR;
    s.counts = c.makeBuffer(4, input);
    const bool paged = place != Placement::kOwnMemory;
    const VkDeviceSize infosAt = paged ? 8192 : 0;  // an interior page of a 32 KiB buffer
    s.infos = paged ? c.makeBuffer(32768, input | storage) : c.makeBuffer(sizeof(s.cluster), input);
    s.infosHost = s.infos.mapped + infosAt;
    const VkDeviceAddress infosAddress = s.infos.address + infosAt;
    s.vertices = c.makeBuffer(9 * sizeof(float), input);
    s.indices = c.makeBuffer(3 * sizeof(uint32_t), input);
    s.implicitData = c.makeBuffer(sizes.accelerationStructureSize, storage);
    s.scratch = c.makeBuffer(sizes.buildScratchSize, 0);
    s.dstAddresses = c.makeBuffer(sizeof(VkDeviceAddress), storage);
    s.dstSizes = c.makeBuffer(sizeof(uint32_t), storage);
    const uint32_t one = 1;
    std::memcpy(s.counts.mapped, &one, sizeof one);
    const float triangle[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    std::memcpy(s.vertices.mapped, triangle, sizeof triangle);
    const uint32_t corners[3] = {0, 1, 2};
    std::memcpy(s.indices.mapped, corners, sizeof corners);
    VkClusterAccelerationStructureBuildTriangleClusterInfoNV& cluster = s.cluster;
    cluster.clusterID = 10;
    cluster.triangleCount = 1;
    cluster.vertexCount = 3;
    cluster.indexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_32BIT_NV;
    cluster.vertexBufferStride = 3 * sizeof(float);
    cluster.indexBuffer = s.indices.address;
    cluster.vertexBuffer = s.vertices.address;
    std::memcpy(s.infosHost, &cluster, sizeof cluster);
    VkClusterAccelerationStructureCommandsInfoNV& build = s.build;
    build.dstImplicitData =
        place == Placement::kLayerWrites ? infosAddress + 1024 : s.implicitData.address;
    build.scratchData = s.scratch.address;
    build.dstAddressesArray = {s.dstAddresses.address, sizeof(VkDeviceAddress),
                               sizeof(VkDeviceAddress)};
    build.dstSizesArray = {s.dstSizes.address, sizeof(uint32_t), sizeof(uint32_t)};
    build.srcInfosArray = {infosAddress, sizeof cluster, sizeof cluster};
    build.srcInfosCount = s.counts.address;
}

// The next frame's infos written over this frame's, by the way `place` names.
void rewriteInfos(RewriteScene& s, Placement place) {
    s.cluster.clusterID = 20;
    if (place == Placement::kNeighbour) {
        std::memset(s.infosHost + 2048, 0x5A, 64);  // the same page, bytes no command reads
    } else if (place == Placement::kThread) {
        std::thread([&] { std::memcpy(s.infosHost, &s.cluster, sizeof s.cluster); }).join();
    } else if (place != Placement::kLayerWrites) {
        std::memcpy(s.infosHost, &s.cluster, sizeof s.cluster);
    }
}

constexpr uint64_t kForever = 30ull * 1000 * 1000 * 1000;

// The build waits for a timeline value the host signals only after rewriting the infos and
// making one more (empty) submission: the build has not run when the layer looks.
void rewriteBeforeRun(Context& c, RewriteScene& s, Placement place, VkSubmitInfo submit,
                      VkFence fence) {
    VkSemaphoreTypeCreateInfo type{VK_STRUCTURE_TYPE_SEMAPHORE_TYPE_CREATE_INFO, nullptr,
                                   VK_SEMAPHORE_TYPE_TIMELINE, 0};
    VkSemaphoreCreateInfo semaphoreInfo{VK_STRUCTURE_TYPE_SEMAPHORE_CREATE_INFO, &type, 0};
    VkSemaphore gate;
    CHECK(vkCreateSemaphore(c.device, &semaphoreInfo, nullptr, &gate));
    const uint64_t open = 1;
    VkTimelineSemaphoreSubmitInfo values{
        VK_STRUCTURE_TYPE_TIMELINE_SEMAPHORE_SUBMIT_INFO, nullptr, 1, &open, 0, nullptr};
    const VkPipelineStageFlags stage = VK_PIPELINE_STAGE_ALL_COMMANDS_BIT;
    submit.pNext = &values;
    submit.waitSemaphoreCount = 1;
    submit.pWaitSemaphores = &gate;
    submit.pWaitDstStageMask = &stage;
    CHECK(vkQueueSubmit(c.queue, 1, &submit, fence));
    rewriteInfos(s, place);
    CHECK(vkQueueSubmit(c.queue, 0, nullptr, VK_NULL_HANDLE));
    VkSemaphoreSignalInfo signal{VK_STRUCTURE_TYPE_SEMAPHORE_SIGNAL_INFO, nullptr, gate, open};
    CHECK(vkSignalSemaphore(c.device, &signal));
    CHECK(vkWaitForFences(c.device, 1, &fence, VK_TRUE, kForever));
    vkDestroySemaphore(c.device, gate, nullptr);
}

// Submits the build, rewrites the infos before or after the fence wait, and submits again.
int rewriteAroundWait(Context& c, RewriteScene& s, Rewrite when, Placement place,
                      const VkSubmitInfo& submit, VkFence fence) {
    if (place == Placement::kAppHandler) {  // its handler comes after the layer's
        CHECK(vkQueueSubmit(c.queue, 1, &submit, fence));
        CHECK(vkWaitForFences(c.device, 1, &fence, VK_TRUE, kForever));
        CHECK(vkResetFences(c.device, 1, &fence));
        takeSigsegv();
    }
    CHECK(vkQueueSubmit(c.queue, 1, &submit, fence));
    if (place == Placement::kAppHandler) appGuardPage[0] = 1;  // the app's own fault
    if (when == Rewrite::kBeforeWait) rewriteInfos(s, place);
    CHECK(vkWaitForFences(c.device, 1, &fence, VK_TRUE, kForever));
    if (place == Placement::kAppHandler && appFaults != 1) {
        std::fprintf(stderr, "the application's SIGSEGV handler saw %d faults, not 1\n",
                     appFaults.load());
        return 4;
    }
    if (when == Rewrite::kAfterWait) rewriteInfos(s, place);
    CHECK(vkResetFences(c.device, 1, &fence));
    CHECK(vkQueueSubmit(c.queue, 1, &submit, fence));
    CHECK(vkWaitForFences(c.device, 1, &fence, VK_TRUE, kForever));
    return 0;
}

int hostRewrite(Rewrite when, Placement place = Placement::kOwnMemory) {
    Context c;
    c.createInstance();
    c.createDevice(/*timelineSemaphores=*/true);
    RewriteScene s;
    makeRewriteScene(c, place, s);

    VkCommandBufferAllocateInfo allocInfo{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO, nullptr,
                                          c.pool, VK_COMMAND_BUFFER_LEVEL_PRIMARY, 1};
    VkCommandBuffer cb;
    CHECK(vkAllocateCommandBuffers(c.device, &allocInfo, &cb));
    VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO, nullptr, 0,
                                   nullptr};
    CHECK(vkBeginCommandBuffer(cb, &begin));
    c.cmdBuildClusters(cb, &s.build);
    CHECK(vkEndCommandBuffer(cb));
    VkFenceCreateInfo fenceInfo{VK_STRUCTURE_TYPE_FENCE_CREATE_INFO, nullptr, 0};
    VkFence fence;
    CHECK(vkCreateFence(c.device, &fenceInfo, nullptr, &fence));
    VkSubmitInfo submit{};
    submit.sType = VK_STRUCTURE_TYPE_SUBMIT_INFO;
    submit.commandBufferCount = 1;
    submit.pCommandBuffers = &cb;
    int rc = 0;
    if (when == Rewrite::kBeforeRun) {
        rewriteBeforeRun(c, s, place, submit, fence);
    } else {
        rc = rewriteAroundWait(c, s, when, place, submit, fence);
    }
    if (rc == 0) vkDestroyFence(c.device, fence, nullptr);
    return rc;
}

// A compute dispatch with two storage buffers bound (one dynamic), for the layer's record of
// what a dispatch can write. The shader does nothing: only the binding state matters.
int dispatch(const char* outPath) {
    Context c;
    c.createInstance();
    c.createDevice();
    Buffer a = c.makeBuffer(1024, 0, 0);
    Buffer b = c.makeBuffer(4096, 0, 0);
    // OpCapability Shader; OpMemoryModel Logical GLSL450; OpEntryPoint GLCompute %1 "main";
    // OpExecutionMode %1 LocalSize 1 1 1; void main() {}
    const uint32_t spirv[] = {0x07230203, 0x00010000, 0,          5, 0, 0x00020011, 1, 0x0003000E,
                              0,          1,          0x0005000F, 5, 1, 0x6E69616D, 0, 0x00060010,
                              1,          17,         1,          1, 1, 0x00020013, 2, 0x00030021,
                              3,          2,          0x00050036, 2, 1, 0,          3, 0x000200F8,
                              4,          0x000100FD, 0x00010038};
    VkShaderModuleCreateInfo moduleInfo{VK_STRUCTURE_TYPE_SHADER_MODULE_CREATE_INFO, nullptr, 0,
                                        sizeof spirv, spirv};
    VkShaderModule module;
    CHECK(vkCreateShaderModule(c.device, &moduleInfo, nullptr, &module));
    const VkDescriptorSetLayoutBinding bindings[2] = {{0, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, 1,
                                                       VK_SHADER_STAGE_COMPUTE_BIT, nullptr},
                                                      {1, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER_DYNAMIC,
                                                       1, VK_SHADER_STAGE_COMPUTE_BIT, nullptr}};
    VkDescriptorSetLayoutCreateInfo layoutInfo{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_LAYOUT_CREATE_INFO,
                                               nullptr, 0, 2, bindings};
    VkDescriptorSetLayout setLayout;
    CHECK(vkCreateDescriptorSetLayout(c.device, &layoutInfo, nullptr, &setLayout));
    VkPipelineLayoutCreateInfo pipelineLayoutInfo{
        VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO, nullptr, 0, 1, &setLayout, 0, nullptr};
    VkPipelineLayout pipelineLayout;
    CHECK(vkCreatePipelineLayout(c.device, &pipelineLayoutInfo, nullptr, &pipelineLayout));
    VkComputePipelineCreateInfo pipelineInfo{};
    pipelineInfo.sType = VK_STRUCTURE_TYPE_COMPUTE_PIPELINE_CREATE_INFO;
    pipelineInfo.stage = {VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO,
                          nullptr,
                          0,
                          VK_SHADER_STAGE_COMPUTE_BIT,
                          module,
                          "main",
                          nullptr};
    pipelineInfo.layout = pipelineLayout;
    VkPipeline pipeline;
    CHECK(vkCreateComputePipelines(c.device, VK_NULL_HANDLE, 1, &pipelineInfo, nullptr, &pipeline));
    const VkDescriptorPoolSize sizes[2] = {{VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, 1},
                                           {VK_DESCRIPTOR_TYPE_STORAGE_BUFFER_DYNAMIC, 1}};
    VkDescriptorPoolCreateInfo poolInfo{
        VK_STRUCTURE_TYPE_DESCRIPTOR_POOL_CREATE_INFO, nullptr, 0, 1, 2, sizes};
    VkDescriptorPool pool;
    CHECK(vkCreateDescriptorPool(c.device, &poolInfo, nullptr, &pool));
    VkDescriptorSetAllocateInfo setInfo{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_ALLOCATE_INFO, nullptr,
                                        pool, 1, &setLayout};
    VkDescriptorSet set;
    CHECK(vkAllocateDescriptorSets(c.device, &setInfo, &set));
    const VkDescriptorBufferInfo infoA{a.buffer, 256, 512};
    const VkDescriptorBufferInfo infoB{b.buffer, 0, 1024};
    const VkWriteDescriptorSet writes[2] = {{VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET, nullptr, set,
                                             0, 0, 1, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, nullptr,
                                             &infoA, nullptr},
                                            {VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET, nullptr, set,
                                             1, 0, 1, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER_DYNAMIC,
                                             nullptr, &infoB, nullptr}};
    vkUpdateDescriptorSets(c.device, 2, writes, 0, nullptr);

    VkCommandBuffer cb = c.beginCommands();
    vkCmdBindPipeline(cb, VK_PIPELINE_BIND_POINT_COMPUTE, pipeline);
    uint32_t dynamicOffset = 256;
    vkCmdBindDescriptorSets(cb, VK_PIPELINE_BIND_POINT_COMPUTE, pipelineLayout, 0, 1, &set, 1,
                            &dynamicOffset);
    vkCmdDispatch(cb, 2, 3, 4);
    dynamicOffset = 1024;
    vkCmdBindDescriptorSets(cb, VK_PIPELINE_BIND_POINT_COMPUTE, pipelineLayout, 0, 1, &set, 1,
                            &dynamicOffset);
    vkCmdDispatch(cb, 1, 1, 1);
    c.submitAndWait(cb);

    nlohmann::json out = {{"pipeline", (uint64_t)pipeline},
                          {"a", {{"buffer", (uint64_t)a.buffer}, {"address", a.address}}},
                          {"b", {{"buffer", (uint64_t)b.buffer}, {"address", b.address}}}};
    std::ofstream(outPath) << out.dump(1);
    vkDestroyPipeline(c.device, pipeline, nullptr);
    vkDestroyDescriptorPool(c.device, pool, nullptr);
    vkDestroyPipelineLayout(c.device, pipelineLayout, nullptr);
    vkDestroyDescriptorSetLayout(c.device, setLayout, nullptr);
    vkDestroyShaderModule(c.device, module, nullptr);
    return 0;
}

int pauseCost(int builds) {
    Context c;
    c.createInstance();
    c.createDevice();
    Buffer counts = c.makeBuffer(256, 0, 0);  // srcInfosCount 0: the builds execute nothing
    Buffer infos = c.makeBuffer(256, 0, 0);
    VkClusterAccelerationStructureTriangleClusterInputNV triangleInput{};
    triangleInput.sType =
        VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_TRIANGLE_CLUSTER_INPUT_NV;
    triangleInput.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    VkClusterAccelerationStructureCommandsInfoNV build{};
    build.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV;
    build.input.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_INPUT_INFO_NV;
    build.input.maxAccelerationStructureCount = 1;
    build.input.opType = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV;
    build.input.opInput.pTriangleClusters = &triangleInput;
    build.srcInfosArray = {infos.address, 0, 64};
    build.srcInfosCount = counts.address;
    double seconds[2] = {0, 0};
    for (int pass = 0; pass < 2; ++pass) {
        const int n = pass == 0 ? 0 : builds;
        VkCommandBuffer cb = c.beginCommands();
        vkCmdFillBuffer(cb, counts.buffer, 0, 4, 0);
        for (int i = 0; i < n; ++i) c.cmdBuildClusters(cb, &build);
        const auto start = std::chrono::steady_clock::now();
        c.submitAndWait(cb);
        seconds[pass] =
            std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    }
    std::printf("builds=%d empty_submit_ms=%.3f submit_ms=%.3f per_build_ms=%.4f\n", builds,
                seconds[0] * 1e3, seconds[1] * 1e3, (seconds[1] - seconds[0]) * 1e3 / builds);
    return 0;
}

// served_scene.h's buffers, filled, and its two commands, on a device with the extension.
struct ServedSceneSetUp {
    Buffer vertices, indices, infos, counts, dstAddresses, dstSizes, implicitData, scratch,
        blasInfos, blasDstAddresses, blasDstSizes, blasImplicit, blasScratch;
    VkAccelerationStructureBuildSizesInfoKHR clusterSizes{}, blasSizes{};
    served_scene::Commands commands;  // (points into itself: filled in place)
};

void setUpServedScene(Context& c, ServedSceneSetUp& s) {
    served_scene::Commands sizing;
    served_scene::makeCommands({}, sizing);
    VkAccelerationStructureBuildSizesInfoKHR& clusterSizes = s.clusterSizes;
    clusterSizes = {VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_SIZES_INFO_KHR, nullptr, 0, 0,
                    0};
    VkAccelerationStructureBuildSizesInfoKHR& blasSizes = s.blasSizes;
    blasSizes = {VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_SIZES_INFO_KHR, nullptr, 0, 0, 0};
    c.getBuildSizes(c.device, &sizing.clusters.input, &clusterSizes);
    c.getBuildSizes(c.device, &sizing.blas.input, &blasSizes);
    if (!clusterSizes.accelerationStructureSize || !blasSizes.accelerationStructureSize)
        fail("build sizes of 0");

    const VkBufferUsageFlags input =
        VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR;
    const VkBufferUsageFlags storage = VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR;
    served_scene::Inputs probe = served_scene::makeInputs({});
    s.vertices = c.makeBuffer(probe.vertices.size() * 4, input, 0xEE);
    s.indices = c.makeBuffer(probe.indices.size() * 4, input, 0xEE);
    s.infos = c.makeBuffer(served_scene::kInfoStride * served_scene::kMaxClusters, input, 0xEE);
    s.counts = c.makeBuffer(8, input, 0xEE);
    s.dstAddresses = c.makeBuffer(8 * served_scene::kMaxClusters, storage | input, 0xEE);
    s.dstSizes = c.makeBuffer(4 * served_scene::kMaxClusters, storage, 0xEE);
    s.implicitData = c.makeBuffer(clusterSizes.accelerationStructureSize, storage, 0xEE);
    s.scratch = c.makeBuffer(clusterSizes.buildScratchSize, 0, 0xEE);
    s.blasInfos = c.makeBuffer(sizeof(VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV),
                               input, 0xEE);
    s.blasDstAddresses = c.makeBuffer(8, storage, 0xEE);
    s.blasDstSizes = c.makeBuffer(4, storage, 0xEE);
    s.blasImplicit = c.makeBuffer(blasSizes.accelerationStructureSize, storage, 0xEE);
    s.blasScratch = c.makeBuffer(blasSizes.buildScratchSize, 0, 0xEE);

    served_scene::Addresses a{s.vertices.address,     s.indices.address,
                              s.infos.address,        s.counts.address,
                              s.dstAddresses.address, s.dstSizes.address,
                              s.implicitData.address, s.scratch.address,
                              s.blasInfos.address,    s.blasDstAddresses.address,
                              s.blasDstSizes.address, s.blasImplicit.address,
                              s.blasScratch.address};
    served_scene::Inputs in = served_scene::makeInputs(a);
    std::memcpy(s.vertices.mapped, in.vertices.data(), in.vertices.size() * 4);
    std::memcpy(s.indices.mapped, in.indices.data(), in.indices.size() * 4);
    std::memcpy(s.infos.mapped, in.infos.data(), in.infos.size() * served_scene::kInfoStride);
    std::memcpy(s.counts.mapped, in.counts, sizeof in.counts);
    std::memcpy(s.blasInfos.mapped, &in.blasInfo, sizeof in.blasInfo);
    served_scene::makeCommands(a, s.commands);
}

int serve(const char* outPath) {
    Context c;
    c.createInstance();
    if (!c.hasClusterExtension()) {
        std::printf("VK_NV_cluster_acceleration_structure is not supported\n");
        return 3;
    }
    c.createDevice();
    VkPhysicalDeviceClusterAccelerationStructurePropertiesNV p{};
    p.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_CLUSTER_ACCELERATION_STRUCTURE_PROPERTIES_NV;
    VkPhysicalDeviceProperties2 properties2{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2, &p, {}};
    vkGetPhysicalDeviceProperties2(c.physicalDevice, &properties2);
    ServedSceneSetUp scene;
    setUpServedScene(c, scene);
    const served_scene::Commands& commands = scene.commands;
    const VkAccelerationStructureBuildSizesInfoKHR &clusterSizes = scene.clusterSizes,
                                                   &blasSizes = scene.blasSizes;
    const Buffer &vertices = scene.vertices, &indices = scene.indices, &infos = scene.infos,
                 &counts = scene.counts, &dstAddresses = scene.dstAddresses,
                 &dstSizes = scene.dstSizes, &implicitData = scene.implicitData,
                 &scratch = scene.scratch, &blasInfos = scene.blasInfos,
                 &blasDstAddresses = scene.blasDstAddresses, &blasDstSizes = scene.blasDstSizes,
                 &blasImplicit = scene.blasImplicit, &blasScratch = scene.blasScratch;

    VkCommandBuffer cb = c.beginCommands();
    c.cmdBuildClusters(cb, &commands.clusters);
    // The bottom level reads the cluster objects and the addresses the first build wrote.
    VkMemoryBarrier barrier{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr,
                            VK_ACCESS_ACCELERATION_STRUCTURE_WRITE_BIT_KHR,
                            VK_ACCESS_ACCELERATION_STRUCTURE_READ_BIT_KHR |
                                VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_INDIRECT_COMMAND_READ_BIT};
    vkCmdPipelineBarrier(cb, VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                         VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR, 0, 1, &barrier, 0,
                         nullptr, 0, nullptr);
    c.cmdBuildClusters(cb, &commands.blas);
    VkMemoryBarrier toHost{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr,
                           VK_ACCESS_ACCELERATION_STRUCTURE_WRITE_BIT_KHR, VK_ACCESS_HOST_READ_BIT};
    vkCmdPipelineBarrier(cb, VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                         VK_PIPELINE_STAGE_HOST_BIT, 0, 1, &toHost, 0, nullptr, 0, nullptr);
    c.submitAndWait(cb);
    CHECK(vkQueueWaitIdle(c.queue));

    auto bufferJson = [](const Buffer& b) {
        return nlohmann::json{{"address", b.address},
                              {"size", b.size},
                              {"bytes", hex(b.mapped, b.size)}};
    };
    nlohmann::json out;
    out["properties"] = {{"clusterByteAlignment", p.clusterByteAlignment},
                         {"clusterBottomLevelByteAlignment", p.clusterBottomLevelByteAlignment}};
    out["buildSizes"] = {{"clusters",
                          {{"accelerationStructureSize", clusterSizes.accelerationStructureSize},
                           {"buildScratchSize", clusterSizes.buildScratchSize}}},
                         {"blas",
                          {{"accelerationStructureSize", blasSizes.accelerationStructureSize},
                           {"buildScratchSize", blasSizes.buildScratchSize}}}};
    // Addresses for the host recomputation; bytes as the builds left them.
    out["buffers"] = {{"vertices", bufferJson(vertices)},
                      {"indices", bufferJson(indices)},
                      {"infos", bufferJson(infos)},
                      {"counts", bufferJson(counts)},
                      {"dstAddresses", bufferJson(dstAddresses)},
                      {"dstSizes", bufferJson(dstSizes)},
                      {"implicitData", bufferJson(implicitData)},
                      {"scratch", bufferJson(scratch)},
                      {"blasInfos", bufferJson(blasInfos)},
                      {"blasDstAddresses", bufferJson(blasDstAddresses)},
                      {"blasDstSizes", bufferJson(blasDstSizes)},
                      {"blasImplicit", bufferJson(blasImplicit)},
                      {"blasScratch", bufferJson(blasScratch)}};
    std::ofstream(outPath) << out.dump(1);
    return 0;
}

// Submits `cb` as the last submission of frame `frame` (a VK_EXT_frame_boundary frame-end mark)
// and waits for it.
// Submits one frame's commands, ending the frame; with a `gate`, the submission first waits for
// the gate's value 1, and the host does not wait for it.
void submitFrame(Context& c, VkCommandBuffer cb, uint64_t frame, VkSemaphore gate = nullptr) {
    CHECK(vkEndCommandBuffer(cb));
    VkFrameBoundaryEXT boundary{};
    boundary.sType = VK_STRUCTURE_TYPE_FRAME_BOUNDARY_EXT;
    boundary.flags = VK_FRAME_BOUNDARY_FRAME_END_BIT_EXT;
    boundary.frameID = frame;
    const uint64_t open = 1;
    VkTimelineSemaphoreSubmitInfo values{
        VK_STRUCTURE_TYPE_TIMELINE_SEMAPHORE_SUBMIT_INFO, &boundary, 1, &open, 0, nullptr};
    const VkPipelineStageFlags stage = VK_PIPELINE_STAGE_ALL_COMMANDS_BIT;
    VkSubmitInfo submit{};
    submit.sType = VK_STRUCTURE_TYPE_SUBMIT_INFO;
    submit.pNext = gate ? static_cast<const void*>(&values) : &boundary;
    submit.waitSemaphoreCount = gate ? 1 : 0;
    submit.pWaitSemaphores = &gate;
    submit.pWaitDstStageMask = &stage;
    submit.commandBufferCount = 1;
    submit.pCommandBuffers = &cb;
    CHECK(vkQueueSubmit(c.queue, 1, &submit, VK_NULL_HANDLE));
    if (!gate) CHECK(vkQueueWaitIdle(c.queue));
}

void buildToHostBarrier(VkCommandBuffer cb) {
    VkMemoryBarrier toHost{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr,
                           VK_ACCESS_ACCELERATION_STRUCTURE_WRITE_BIT_KHR, VK_ACCESS_HOST_READ_BIT};
    vkCmdPipelineBarrier(cb, VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                         VK_PIPELINE_STAGE_HOST_BIT, 0, 1, &toHost, 0, nullptr, 0, nullptr);
}

// A frame range starting at frame 2 finds its bottom level's clusters built before it
// (capture/README.md, "Frame ranges"): frame 1's build is the one that still holds them.
int serveFrames(const char* outPath, bool gated) {
    Context c;
    c.createInstance();
    if (!c.hasClusterExtension()) {
        std::printf("VK_NV_cluster_acceleration_structure is not supported\n");
        return 3;
    }
    c.createDevice();
    ServedSceneSetUp scene;
    setUpServedScene(c, scene);
    VkSemaphoreTypeCreateInfo type{VK_STRUCTURE_TYPE_SEMAPHORE_TYPE_CREATE_INFO, nullptr,
                                   VK_SEMAPHORE_TYPE_TIMELINE, 0};
    VkSemaphoreCreateInfo semaphoreInfo{VK_STRUCTURE_TYPE_SEMAPHORE_CREATE_INFO, &type, 0};
    VkSemaphore gate = VK_NULL_HANDLE;
    if (gated) CHECK(vkCreateSemaphore(c.device, &semaphoreInfo, nullptr, &gate));
    for (uint64_t frame : {0, 1}) {
        VkCommandBuffer cb = c.beginCommands();
        c.cmdBuildClusters(cb, &scene.commands.clusters);
        buildToHostBarrier(cb);
        submitFrame(c, cb, frame, frame == 1 ? gate : VK_NULL_HANDLE);
    }
    VkCommandBuffer cb = c.beginCommands();
    c.cmdBuildClusters(cb, &scene.commands.blas);
    buildToHostBarrier(cb);
    submitFrame(c, cb, 2, gate);  // (queue order: after frame 1's, which waits on the gate)
    if (gated) {
        VkSemaphoreSignalInfo signal{VK_STRUCTURE_TYPE_SEMAPHORE_SIGNAL_INFO, nullptr, gate, 1};
        CHECK(vkSignalSemaphore(c.device, &signal));
        CHECK(vkQueueWaitIdle(c.queue));
        vkDestroySemaphore(c.device, gate, nullptr);
    }
    nlohmann::json out;
    out["blasImplicit"] = {{"address", scene.blasImplicit.address},
                           {"bytes", hex(scene.blasImplicit.mapped, scene.blasImplicit.size)}};
    uint64_t blas = 0;
    std::memcpy(&blas, scene.blasDstAddresses.mapped, 8);
    out["blasAddress"] = blas;
    std::ofstream(outPath) << out.dump(1);
    return 0;
}

}  // namespace

int main(int argc, char** argv) {
    if (argc == 3 && std::strcmp(argv[1], "limits") == 0) return limits(argv[2]);
    if (argc == 3 && std::strcmp(argv[1], "serve") == 0) return serve(argv[2]);
    if (argc == 3 && std::strcmp(argv[1], "serve-frames") == 0) return serveFrames(argv[2], false);
    if (argc == 3 && std::strcmp(argv[1], "serve-frames-gated") == 0)
        return serveFrames(argv[2], true);
    if (argc == 3 && std::strcmp(argv[1], "exactness") == 0) return exactness(argv[2]);
    if (argc == 3 && std::strcmp(argv[1], "dispatch") == 0) return dispatch(argv[2]);
    if (argc == 3 && std::strcmp(argv[1], "resubmit") == 0)
        return resubmit(std::max(1, std::atoi(argv[2])));
    if ((argc == 3 || argc == 4) && std::strcmp(argv[1], "host-rewrite") == 0) {
        const std::map<std::string, Placement> places = {{"paged", Placement::kPaged},
                                                         {"neighbour", Placement::kNeighbour},
                                                         {"thread", Placement::kThread},
                                                         {"app-handler", Placement::kAppHandler},
                                                         {"layer-writes", Placement::kLayerWrites}};
        Placement place = Placement::kOwnMemory;
        if (argc == 4) {
            auto it = places.find(argv[3]);
            if (it == places.end()) fail("unknown placement");
            place = it->second;
        }
        if (std::strcmp(argv[2], "before-wait") == 0)
            return hostRewrite(Rewrite::kBeforeWait, place);
        if (std::strcmp(argv[2], "after-wait") == 0) return hostRewrite(Rewrite::kAfterWait, place);
        if (std::strcmp(argv[2], "before-run") == 0) return hostRewrite(Rewrite::kBeforeRun, place);
    }
    if (argc == 3 && std::strcmp(argv[1], "pause-cost") == 0)
        return pauseCost(std::max(1, std::atoi(argv[2])));
    std::fprintf(stderr, "usage: cluster_capture_app limits|exactness OUT.json | pause-cost N\n");
    return 1;
}
