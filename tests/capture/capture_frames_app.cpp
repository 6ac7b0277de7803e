// SPDX-License-Identifier: Apache-2.0
// A frame loop over VK_NV_cluster_acceleration_structure for the capture layer's robustness
// tests and its overhead benchmark. Each frame the host moves one eighth of the clusters, a
// GPU copy fills srcInfosArray, a triangle-cluster build and a bottom-level build over its
// dstAddressesArray run, and the host waits on a fence (and sets/resets an event, and signals
// and waits on a timeline semaphore).
//
//   capture_frames_app frames N [options]
//     --clusters C        clusters per build (default 64)
//     --out FILE          JSON: what the builds wrote in the last frame (hex)
//     --bad-cluster-id    cluster 0 gets clusterID 0xFFFFFFFF (a rule the engine names)
//     --race-at K         after submitting frame K, before its wait: the host rewrites a vertex
//                         the build reads (a host-write race, on a walk the watch reused)
//     --host-infos        the host writes srcInfosArray once, and no GPU copy does each frame (as
//                         on a GPU, where that copy faults nothing; lavapipe's CPU copy writes
//                         pages the host-write watch holds, in every frame)
//     --exit-at K         after submitting frame K: exit(0) without waiting or cleanup
//     --abort-at K        after submitting frame K: abort()
//     --stop-at K         after submitting frame K: sleep until killed
//     --wait-for FILE     before frame K of the three above: wait until FILE exists
//   capture_frames_app simultaneous OUT.json
//     one SIMULTANEOUS_USE command buffer submitted twice in one vkQueueSubmit and twice more
//     in two; its build reads a count that the command buffer itself rewrites after the build.
//   capture_frames_app twoqueues OUT.json [--hold-first]
//     the simultaneous-use command buffer of `simultaneous`, submitted to queue 0 and at once to
//     queue 1 (needs a family with two queues); --hold-first makes its executions wait on an
//     event the host sets only after both submissions returned.
//   capture_frames_app secondary OUT.json [--skip-barrier] [--bad-cluster-id]
//     a primary command buffer copies srcInfosArray, runs a secondary (SIMULTANEOUS_USE) that
//     holds the cluster build, rewrites the count the build reads and runs the secondary again;
//     --skip-barrier leaves out the secondary's barrier before its build; --bad-cluster-id as
//     for frames.
//
// Prints "frames=N loop_ms=T loop_cpu_ms=C" on success: the frame loop's wall time, and the CPU
// time of all the process's threads (driver and layer included) during it.
#include "cluster_test_device.h"

#include <array>
#include <chrono>
#include <sys/resource.h>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <thread>
#include <vector>

namespace {

using namespace clastrace::testapp;

// Timeline semaphores on (the frame loop signals and waits on one). Each mode tears down
// itself; the exit/abort/stop modes leave on purpose without doing so.
struct Context : ClusterTestDevice {
    explicit Context(uint32_t queues = 1) {
        createInstance();
        createDevice(/*timelineSemaphores=*/true, queues);
    }
};

void barrier(VkCommandBuffer cb, VkPipelineStageFlags src, VkAccessFlags srcAccess,
             VkPipelineStageFlags dst, VkAccessFlags dstAccess) {
    VkMemoryBarrier b{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr, srcAccess, dstAccess};
    vkCmdPipelineBarrier(cb, src, dst, 0, 1, &b, 0, nullptr, 0, nullptr);
}

constexpr uint32_t kQuadsX = 8, kQuadsY = 4, kVertices = (kQuadsX + 1) * (kQuadsY + 1),
                   kTriangles = 2 * kQuadsX * kQuadsY;
const VkBufferUsageFlags kInput =
    VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR;
const VkBufferUsageFlags kStorage = VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR;

struct FrameOptions {
    int frames = 10;
    uint32_t clusters = 64;
    std::string out, waitFor;
    bool badClusterId = false, hostInfos = false;
    int exitAt = -1, abortAt = -1, stopAt = -1, raceAt = -1;
};

double processCpuMilliseconds() {
    rusage usage{};
    getrusage(RUSAGE_SELF, &usage);
    return (double(usage.ru_utime.tv_sec) + double(usage.ru_stime.tv_sec)) * 1e3 +
           (double(usage.ru_utime.tv_usec) + double(usage.ru_stime.tv_usec)) * 1e-3;
}

// One cluster's triangles: two per quad of the kQuadsX x kQuadsY grid, 3 * kTriangles indices.
void writeGridIndices(uint32_t* out) {
    for (uint32_t y = 0; y < kQuadsY; ++y)
        for (uint32_t x = 0; x < kQuadsX; ++x) {
            const uint32_t v = y * (kQuadsX + 1) + x;
            for (uint32_t i : {v, v + 1, v + kQuadsX + 2, v, v + kQuadsX + 2, v + kQuadsX + 1})
                *out++ = i;
        }
}

void writeVertices(const Buffer& vertices, uint32_t clusters, int frame) {
    auto* v = reinterpret_cast<float*>(vertices.mapped);
    for (uint32_t c = 0; c < clusters; ++c) {
        if (frame > 0 && int(c % 8) != frame % 8)
            continue;  // one eighth of the clusters move per frame
        for (uint32_t y = 0; y <= kQuadsY; ++y)
            for (uint32_t x = 0; x <= kQuadsX; ++x) {
                float* p = v + (uint64_t(c) * kVertices + y * (kQuadsX + 1) + x) * 3;
                p[0] = float(c % 16) * 9.0f + float(x);
                p[1] = float(c / 16) * 5.0f + float(y);
                p[2] = float(frame) * 0.125f + float(x * y % 3) * 0.25f;
            }
    }
}

// An implicit-destination build of up to `clusters` grid clusters (kTriangles, kVertices each):
// `build` points at `triangles`, so the caller keeps both alive together.
void describeClusterBuild(uint32_t clusters,
                          VkClusterAccelerationStructureTriangleClusterInputNV& triangles,
                          VkClusterAccelerationStructureCommandsInfoNV& build) {
    triangles.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_TRIANGLE_CLUSTER_INPUT_NV;
    triangles.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    triangles.maxGeometryIndexValue = 0;
    triangles.maxClusterUniqueGeometryCount = 1;
    triangles.maxClusterTriangleCount = kTriangles;
    triangles.maxClusterVertexCount = kVertices;
    triangles.maxTotalTriangleCount = clusters * kTriangles;
    triangles.maxTotalVertexCount = clusters * kVertices;
    build.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV;
    build.input.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_INPUT_INFO_NV;
    build.input.maxAccelerationStructureCount = clusters;
    build.input.opType = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV;
    build.input.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
    build.input.opInput.pTriangleClusters = &triangles;
}

// The frames' scene: one implicit-destination cluster build of `n` grid clusters and one bottom
// level over them, their buffers, and the commands infos pointing into this struct (so it is
// built in place and not moved).
struct FrameScene {
    using Info = VkClusterAccelerationStructureBuildTriangleClusterInfoNV;
    uint32_t n = 0;
    VkClusterAccelerationStructureTriangleClusterInputNV triangles{};
    VkClusterAccelerationStructureCommandsInfoNV build{};
    VkClusterAccelerationStructureClustersBottomLevelInputNV bottom{};
    VkClusterAccelerationStructureCommandsInfoNV blas{};
    Buffer vertices, indices, infoSource, infos, counts, dstAddresses, dstSizes, implicit, scratch;
    Buffer blasInfo, blasAddress, blasSize, blasImplicit, blasScratch;

    std::array<Buffer*, 14> buffers() {
        return {&vertices,     &indices,  &infoSource,   &infos,      &counts,
                &dstAddresses, &dstSizes, &implicit,     &scratch,    &blasInfo,
                &blasAddress,  &blasSize, &blasImplicit, &blasScratch};
    }
};

void describeBottomLevelBuild(FrameScene& s) {
    s.bottom.sType =
        VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_CLUSTERS_BOTTOM_LEVEL_INPUT_NV;
    s.bottom.maxTotalClusterCount = s.n;
    s.bottom.maxClusterCountPerAccelerationStructure = s.n;
    VkClusterAccelerationStructureCommandsInfoNV& blas = s.blas;
    blas.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV;
    blas.input.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_INPUT_INFO_NV;
    blas.input.maxAccelerationStructureCount = 1;
    blas.input.opType = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV;
    blas.input.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
    blas.input.opInput.pClustersBottomLevel = &s.bottom;
}

void makeFrameBuffers(Context& c, FrameScene& s) {
    VkAccelerationStructureBuildSizesInfoKHR clusterSizes{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_SIZES_INFO_KHR, nullptr, 0, 0, 0};
    VkAccelerationStructureBuildSizesInfoKHR blasSizes = clusterSizes;
    c.getBuildSizes(c.device, &s.build.input, &clusterSizes);
    c.getBuildSizes(c.device, &s.blas.input, &blasSizes);
    if (!clusterSizes.accelerationStructureSize || !blasSizes.accelerationStructureSize)
        fail("build sizes of 0");
    const uint64_t n = s.n;
    s.vertices = c.makeBuffer(n * kVertices * 12, kInput);
    s.indices = c.makeBuffer(n * kTriangles * 12, kInput);
    s.infoSource = c.makeBuffer(n * sizeof(FrameScene::Info), 0);
    s.infos = c.makeBuffer(n * sizeof(FrameScene::Info), kInput);
    s.counts = c.makeBuffer(8, kInput);
    s.dstAddresses = c.makeBuffer(n * 8, kStorage | kInput);
    s.dstSizes = c.makeBuffer(n * 4, kStorage);
    s.implicit = c.makeBuffer(clusterSizes.accelerationStructureSize, kStorage);
    s.scratch = c.makeBuffer(clusterSizes.buildScratchSize, kStorage);
    s.blasInfo =
        c.makeBuffer(sizeof(VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV), kInput);
    s.blasAddress = c.makeBuffer(8, kStorage);
    s.blasSize = c.makeBuffer(4, kStorage);
    s.blasImplicit = c.makeBuffer(blasSizes.accelerationStructureSize, kStorage);
    s.blasScratch = c.makeBuffer(blasSizes.buildScratchSize, kStorage);
}

// The grid's indices, the clusters' infos (in the staging buffer, or already in place with
// `hostInfos`), the counts and the bottom level's one info.
void writeFrameInputs(const FrameOptions& o, FrameScene& s) {
    using Info = FrameScene::Info;
    auto* index = reinterpret_cast<uint32_t*>(s.indices.mapped);
    auto* info = reinterpret_cast<Info*>(s.infoSource.mapped);
    for (uint32_t k = 0; k < s.n; ++k) {
        writeGridIndices(index + uint64_t(k) * kTriangles * 3);
        Info& i = info[k];
        i = Info{};
        i.clusterID = (o.badClusterId && k == 0) ? 0xFFFFFFFFu : 1000 + k;
        i.triangleCount = kTriangles;
        i.vertexCount = kVertices;
        i.indexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_32BIT_NV;
        i.indexBuffer = s.indices.address + uint64_t(k) * kTriangles * 12;
        i.vertexBuffer = s.vertices.address + uint64_t(k) * kVertices * 12;
    }
    if (o.hostInfos) std::memcpy(s.infos.mapped, s.infoSource.mapped, s.infos.size);
    const uint32_t countValues[2] = {s.n, 1};
    std::memcpy(s.counts.mapped, countValues, sizeof countValues);
    VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV reference{};
    reference.clusterReferencesCount = s.n;
    reference.clusterReferencesStride = 8;
    reference.clusterReferences = s.dstAddresses.address;
    std::memcpy(s.blasInfo.mapped, &reference, sizeof reference);
}

void pointBuildsAtBuffers(FrameScene& s) {
    using Info = FrameScene::Info;
    VkClusterAccelerationStructureCommandsInfoNV& build = s.build;
    build.dstImplicitData = s.implicit.address;
    build.scratchData = s.scratch.address;
    build.dstAddressesArray = {s.dstAddresses.address, 8, s.dstAddresses.size};
    build.dstSizesArray = {s.dstSizes.address, 4, s.dstSizes.size};
    build.srcInfosArray = {s.infos.address, sizeof(Info), s.infos.size};
    build.srcInfosCount = s.counts.address;
    VkClusterAccelerationStructureCommandsInfoNV& blas = s.blas;
    blas.dstImplicitData = s.blasImplicit.address;
    blas.scratchData = s.blasScratch.address;
    blas.dstAddressesArray = {s.blasAddress.address, 8, 8};
    blas.dstSizesArray = {s.blasSize.address, 4, 4};
    blas.srcInfosArray = {s.blasInfo.address, 0, s.blasInfo.size};
    blas.srcInfosCount = s.counts.address + 4;
}

void makeFrameScene(Context& c, const FrameOptions& o, FrameScene& s) {
    s.n = o.clusters;
    describeClusterBuild(s.n, s.triangles, s.build);
    describeBottomLevelBuild(s);
    makeFrameBuffers(c, s);
    writeFrameInputs(o, s);
    pointBuildsAtBuffers(s);
}

// What a frame waits and signals with: its command buffer, fence, event and the host's
// timeline semaphore.
struct FrameSync {
    VkCommandBuffer cb = VK_NULL_HANDLE;
    VkFence fence = VK_NULL_HANDLE;
    VkEvent frameEvent = VK_NULL_HANDLE;
    VkSemaphore timeline = VK_NULL_HANDLE;
};

FrameSync makeFrameSync(Context& c) {
    FrameSync y;
    VkCommandBufferAllocateInfo allocInfo{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO, nullptr,
                                          c.pool, VK_COMMAND_BUFFER_LEVEL_PRIMARY, 1};
    CHECK(vkAllocateCommandBuffers(c.device, &allocInfo, &y.cb));
    VkFenceCreateInfo fenceInfo{VK_STRUCTURE_TYPE_FENCE_CREATE_INFO, nullptr, 0};
    CHECK(vkCreateFence(c.device, &fenceInfo, nullptr, &y.fence));
    VkEventCreateInfo eventInfo{VK_STRUCTURE_TYPE_EVENT_CREATE_INFO, nullptr, 0};
    CHECK(vkCreateEvent(c.device, &eventInfo, nullptr, &y.frameEvent));
    VkSemaphoreTypeCreateInfo timelineType{VK_STRUCTURE_TYPE_SEMAPHORE_TYPE_CREATE_INFO, nullptr,
                                           VK_SEMAPHORE_TYPE_TIMELINE, 0};
    VkSemaphoreCreateInfo semaphoreInfo{VK_STRUCTURE_TYPE_SEMAPHORE_CREATE_INFO, &timelineType, 0};
    CHECK(vkCreateSemaphore(c.device, &semaphoreInfo, nullptr, &y.timeline));
    return y;
}

// Re-recorded every frame, as engines do.
void recordFrame(Context& c, const FrameOptions& o, FrameScene& s, VkCommandBuffer cb) {
    VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO, nullptr,
                                   VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT, nullptr};
    CHECK(vkBeginCommandBuffer(cb, &begin));
    if (!o.hostInfos) {
        VkBufferCopy copy{0, 0, s.infos.size};
        vkCmdCopyBuffer(cb, s.infoSource.buffer, s.infos.buffer, 1, &copy);
        barrier(cb, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_WRITE_BIT,
                VK_PIPELINE_STAGE_ALL_COMMANDS_BIT, VK_ACCESS_MEMORY_READ_BIT);
    }
    c.cmdBuildClusters(cb, &s.build);
    barrier(cb, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT, VK_ACCESS_MEMORY_WRITE_BIT,
            VK_PIPELINE_STAGE_ALL_COMMANDS_BIT, VK_ACCESS_MEMORY_READ_BIT);
    c.cmdBuildClusters(cb, &s.blas);
    barrier(cb, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT, VK_ACCESS_MEMORY_WRITE_BIT,
            VK_PIPELINE_STAGE_HOST_BIT, VK_ACCESS_HOST_READ_BIT);
    CHECK(vkEndCommandBuffer(cb));
}

// The frame's submission, the exits the options ask for at it, then the host's waits.
void submitFrame(Context& c, const FrameOptions& o, FrameScene& s, const FrameSync& y, int f) {
    VkSubmitInfo submit{};
    submit.sType = VK_STRUCTURE_TYPE_SUBMIT_INFO;
    submit.commandBufferCount = 1;
    submit.pCommandBuffers = &y.cb;
    CHECK(vkQueueSubmit(c.queue, 1, &submit, y.fence));
    if (f == o.exitAt) std::exit(0);
    if (f == o.abortAt) std::abort();
    if (f == o.stopAt) {
        std::printf("stopped at frame %d\n", f);
        std::fflush(stdout);
        for (;;) std::this_thread::sleep_for(std::chrono::seconds(1));
    }
    if (f == o.raceAt) reinterpret_cast<float*>(s.vertices.mapped)[1] += 1.0f;
    CHECK(vkSetEvent(c.device, y.frameEvent));
    CHECK(vkWaitForFences(c.device, 1, &y.fence, VK_TRUE, 60ull * 1000 * 1000 * 1000));
    if (vkGetFenceStatus(c.device, y.fence) != VK_SUCCESS)
        fail("fence not signalled after the wait");
    CHECK(vkResetFences(c.device, 1, &y.fence));
    CHECK(vkResetEvent(c.device, y.frameEvent));
    // The host counts frames on a timeline semaphore and waits for its own signal.
    const uint64_t value = uint64_t(f) + 1;
    VkSemaphoreSignalInfo signal{VK_STRUCTURE_TYPE_SEMAPHORE_SIGNAL_INFO, nullptr, y.timeline,
                                 value};
    CHECK(vkSignalSemaphore(c.device, &signal));
    VkSemaphoreWaitInfo wait{
        VK_STRUCTURE_TYPE_SEMAPHORE_WAIT_INFO, nullptr, 0, 1, &y.timeline, &value};
    CHECK(vkWaitSemaphores(c.device, &wait, 60ull * 1000 * 1000 * 1000));
}

void writeFrameOutputs(const std::string& path, const FrameScene& s) {
    std::ofstream out(path);
    out << "{\"dstSizes\": \"" << hex(s.dstSizes.mapped, s.dstSizes.size)
        << "\", \"dstAddresses\": \"" << hex(s.dstAddresses.mapped, s.dstAddresses.size)
        << "\", \"implicit\": \"" << hex(s.implicit.mapped, s.implicit.size)
        << "\", \"blasImplicit\": \"" << hex(s.blasImplicit.mapped, s.blasImplicit.size) << "\"}\n";
}

void destroyFrames(Context& c, FrameScene& s, const FrameSync& y) {
    vkDestroyEvent(c.device, y.frameEvent, nullptr);
    vkDestroySemaphore(c.device, y.timeline, nullptr);
    vkDestroyFence(c.device, y.fence, nullptr);
    vkDestroyCommandPool(c.device, c.pool, nullptr);
    for (Buffer* b : s.buffers()) {
        vkDestroyBuffer(c.device, b->buffer, nullptr);
        vkFreeMemory(c.device, b->memory, nullptr);
    }
    vkDestroyDevice(c.device, nullptr);
    vkDestroyInstance(c.instance, nullptr);
}

int frames(const FrameOptions& o) {
    Context c;
    FrameScene s;
    makeFrameScene(c, o, s);
    const FrameSync y = makeFrameSync(c);

    const auto start = std::chrono::steady_clock::now();
    const double cpuStart = processCpuMilliseconds();
    for (int f = 0; f < o.frames; ++f) {
        const bool last = f == o.exitAt || f == o.abortAt || f == o.stopAt;
        if (last && !o.waitFor.empty())
            while (!std::filesystem::exists(o.waitFor))
                std::this_thread::sleep_for(std::chrono::milliseconds(5));
        writeVertices(s.vertices, s.n, f);
        recordFrame(c, o, s, y.cb);
        submitFrame(c, o, s, y, f);
    }
    const double loopMs =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
    const double loopCpuMs = processCpuMilliseconds() - cpuStart;
    CHECK(vkQueueWaitIdle(c.queue));
    CHECK(vkDeviceWaitIdle(c.device));
    if (!o.out.empty()) writeFrameOutputs(o.out, s);
    std::printf("frames=%d loop_ms=%.3f loop_cpu_ms=%.3f\n", o.frames, loopMs, loopCpuMs);
    destroyFrames(c, s, y);
    return 0;
}

// Two triangle clusters whose build reads its count at counts[0] (1) while counts[1] holds 2:
// the execution modes below make a later execution build both by copying counts[1] over
// counts[0] on the GPU. With `infosFromStaging` srcInfosArray is filled by a GPU copy from
// `staging` (recordInfosCopy), else by the host.
struct CountedClusterScene {
    using Info = VkClusterAccelerationStructureBuildTriangleClusterInfoNV;
    Context& c;
    Buffer vertices, indices, staging, infos, counts, dstSizes, dstAddresses, implicit, scratch;
    VkClusterAccelerationStructureTriangleClusterInputNV triangles{};
    VkClusterAccelerationStructureCommandsInfoNV build{};

    CountedClusterScene(Context& context, uint32_t firstClusterId, bool badClusterId,
                        bool infosFromStaging)
        : c(context) {
        vertices = c.makeBuffer(2 * kVertices * 12, kInput);
        indices = c.makeBuffer(kTriangles * 12, kInput);
        staging = c.makeBuffer(2 * sizeof(Info), 0);
        infos = c.makeBuffer(2 * sizeof(Info), kInput);
        counts = c.makeBuffer(8, kInput);
        dstSizes = c.makeBuffer(8, kStorage);
        dstAddresses = c.makeBuffer(16, kStorage);
        writeVertices(vertices, 2, 0);
        writeGridIndices(reinterpret_cast<uint32_t*>(indices.mapped));
        for (uint32_t k = 0; k < 2; ++k) {
            Info i{};
            i.clusterID = badClusterId && k == 0 ? 0xFFFFFFFFu : firstClusterId + k;
            i.triangleCount = kTriangles;
            i.vertexCount = kVertices;
            i.indexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_32BIT_NV;
            i.indexBuffer = indices.address;
            i.vertexBuffer = vertices.address + k * kVertices * 12;
            std::memcpy((infosFromStaging ? staging : infos).mapped + k * sizeof(Info), &i,
                        sizeof i);
        }
        const uint32_t countValues[2] = {1, 2};
        std::memcpy(counts.mapped, countValues, sizeof countValues);
        describeClusterBuild(2, triangles, build);
        VkAccelerationStructureBuildSizesInfoKHR sizes{
            VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_SIZES_INFO_KHR, nullptr, 0, 0, 0};
        c.getBuildSizes(c.device, &build.input, &sizes);
        implicit = c.makeBuffer(sizes.accelerationStructureSize, kStorage);
        scratch = c.makeBuffer(sizes.buildScratchSize, kStorage);
        build.dstImplicitData = implicit.address;
        build.scratchData = scratch.address;
        build.dstAddressesArray = {dstAddresses.address, 8, 16};
        build.dstSizesArray = {dstSizes.address, 4, 8};
        build.srcInfosArray = {infos.address, sizeof(Info), 2 * sizeof(Info)};
        build.srcInfosCount = counts.address;
    }
    CountedClusterScene(const CountedClusterScene&) = delete;

    void recordInfosCopy(VkCommandBuffer cb) {
        VkBufferCopy copy{0, 0, 2 * sizeof(Info)};
        vkCmdCopyBuffer(cb, staging.buffer, infos.buffer, 1, &copy);
    }
    void recordCountCopy(VkCommandBuffer cb) {  // counts[1] over counts[0]
        VkBufferCopy copy{4, 0, 4};
        vkCmdCopyBuffer(cb, counts.buffer, counts.buffer, 1, &copy);
    }
    // The build, then (after a barrier from it) the count rewritten for the next execution.
    void recordBuildThenCountCopy(VkCommandBuffer cb) {
        barrier(cb, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_WRITE_BIT,
                VK_PIPELINE_STAGE_ALL_COMMANDS_BIT, VK_ACCESS_MEMORY_READ_BIT);
        c.cmdBuildClusters(cb, &build);
        barrier(cb, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT,
                VK_ACCESS_MEMORY_READ_BIT | VK_ACCESS_MEMORY_WRITE_BIT,
                VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_WRITE_BIT);
        recordCountCopy(cb);
    }
    // OUT.json: what the builds wrote, and the counts, in hex; then everything is destroyed.
    int finish(const char* outPath) {
        std::ofstream(outPath) << "{\"dstSizes\": \"" << hex(dstSizes.mapped, 8)
                               << "\", \"counts\": \"" << hex(counts.mapped, 8) << "\"}\n";
        vkDestroyCommandPool(c.device, c.pool, nullptr);
        for (Buffer* b : {&vertices, &indices, &staging, &infos, &counts, &dstSizes, &dstAddresses,
                          &implicit, &scratch}) {
            vkDestroyBuffer(c.device, b->buffer, nullptr);
            vkFreeMemory(c.device, b->memory, nullptr);
        }
        vkDestroyDevice(c.device, nullptr);
        vkDestroyInstance(c.instance, nullptr);
        return 0;
    }
};

VkCommandBuffer allocateCommandBuffer(Context& c, VkCommandBufferLevel level) {
    VkCommandBufferAllocateInfo info{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO, nullptr,
                                     c.pool, level, 1};
    VkCommandBuffer cb;
    CHECK(vkAllocateCommandBuffers(c.device, &info, &cb));
    return cb;
}

VkSubmitInfo submitOf(const VkCommandBuffer* cbs, uint32_t count) {
    VkSubmitInfo submit{};
    submit.sType = VK_STRUCTURE_TYPE_SUBMIT_INFO;
    submit.commandBufferCount = count;
    submit.pCommandBuffers = cbs;
    return submit;
}

// The first execution builds one cluster and every later one two.
int simultaneous(const char* outPath) {
    Context c;
    CountedClusterScene scene(c, 7, false, false);
    VkCommandBuffer cb = allocateCommandBuffer(c, VK_COMMAND_BUFFER_LEVEL_PRIMARY);
    VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO, nullptr,
                                   VK_COMMAND_BUFFER_USAGE_SIMULTANEOUS_USE_BIT, nullptr};
    CHECK(vkBeginCommandBuffer(cb, &begin));
    scene.recordBuildThenCountCopy(cb);
    CHECK(vkEndCommandBuffer(cb));

    VkCommandBuffer twice[2] = {cb, cb};
    VkSubmitInfo submit = submitOf(twice, 2);
    CHECK(vkQueueSubmit(c.queue, 1, &submit, VK_NULL_HANDLE));  // two executions, one submission
    submit.commandBufferCount = 1;
    CHECK(vkQueueSubmit(c.queue, 1, &submit, VK_NULL_HANDLE));  // and two more while those may run
    CHECK(vkQueueSubmit(c.queue, 1, &submit, VK_NULL_HANDLE));
    CHECK(vkQueueWaitIdle(c.queue));
    return scene.finish(outPath);
}

// The simultaneous-use command buffer on queue 0 and at once on queue 1: the execution on
// queue 0 builds one cluster, the one on queue 1 two.
int twoQueues(const char* outPath, bool holdFirst) {
    Context c(2);
    CountedClusterScene scene(c, 21, false, false);
    VkEvent hold = VK_NULL_HANDLE;
    VkEventCreateInfo eventInfo{VK_STRUCTURE_TYPE_EVENT_CREATE_INFO, nullptr, 0};
    CHECK(vkCreateEvent(c.device, &eventInfo, nullptr, &hold));
    VkCommandBuffer cb = allocateCommandBuffer(c, VK_COMMAND_BUFFER_LEVEL_PRIMARY);
    VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO, nullptr,
                                   VK_COMMAND_BUFFER_USAGE_SIMULTANEOUS_USE_BIT, nullptr};
    CHECK(vkBeginCommandBuffer(cb, &begin));
    if (holdFirst)
        vkCmdWaitEvents(cb, 1, &hold, VK_PIPELINE_STAGE_HOST_BIT,
                        VK_PIPELINE_STAGE_ALL_COMMANDS_BIT, 0, nullptr, 0, nullptr, 0, nullptr);
    scene.recordBuildThenCountCopy(cb);
    CHECK(vkEndCommandBuffer(cb));

    // The second submission is made while the first may still run: the executions of `cb` on the
    // two queues may overlap (the application orders them only through the count it reads).
    VkSubmitInfo submit = submitOf(&cb, 1);
    CHECK(vkQueueSubmit(c.queue, 1, &submit, VK_NULL_HANDLE));
    CHECK(vkQueueSubmit(c.secondQueue, 1, &submit, VK_NULL_HANDLE));
    if (holdFirst) CHECK(vkSetEvent(c.device, hold));
    CHECK(vkQueueWaitIdle(c.queue));
    CHECK(vkQueueWaitIdle(c.secondQueue));
    vkDestroyEvent(c.device, hold, nullptr);
    return scene.finish(outPath);
}

// The build in the secondary reads counts[0] (1 at first); between the two executions the
// primary copies counts[1] (2) over it, so the second execution builds both clusters.
int secondary(const char* outPath, bool skipBarrier, bool badClusterId) {
    Context c;
    CountedClusterScene scene(c, 11, badClusterId, true);
    VkCommandBuffer inner = allocateCommandBuffer(c, VK_COMMAND_BUFFER_LEVEL_SECONDARY);
    VkCommandBuffer outer = allocateCommandBuffer(c, VK_COMMAND_BUFFER_LEVEL_PRIMARY);
    VkCommandBufferInheritanceInfo inheritance{};
    inheritance.sType = VK_STRUCTURE_TYPE_COMMAND_BUFFER_INHERITANCE_INFO;
    VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO, nullptr,
                                   VK_COMMAND_BUFFER_USAGE_SIMULTANEOUS_USE_BIT, &inheritance};
    CHECK(vkBeginCommandBuffer(inner, &begin));
    if (!skipBarrier)  // the copies of the primary (srcInfosArray, count) before the build reads them
        barrier(inner, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_WRITE_BIT,
                VK_PIPELINE_STAGE_ALL_COMMANDS_BIT, VK_ACCESS_MEMORY_READ_BIT);
    c.cmdBuildClusters(inner, &scene.build);
    barrier(inner, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT,
            VK_ACCESS_MEMORY_READ_BIT | VK_ACCESS_MEMORY_WRITE_BIT,
            VK_PIPELINE_STAGE_ALL_COMMANDS_BIT,
            VK_ACCESS_MEMORY_READ_BIT | VK_ACCESS_MEMORY_WRITE_BIT);
    CHECK(vkEndCommandBuffer(inner));

    begin.flags = 0;
    begin.pInheritanceInfo = nullptr;
    CHECK(vkBeginCommandBuffer(outer, &begin));
    scene.recordInfosCopy(outer);
    vkCmdExecuteCommands(outer, 1, &inner);
    scene.recordCountCopy(outer);
    vkCmdExecuteCommands(outer, 1, &inner);
    CHECK(vkEndCommandBuffer(outer));

    VkSubmitInfo submit = submitOf(&outer, 1);
    CHECK(vkQueueSubmit(c.queue, 1, &submit, VK_NULL_HANDLE));
    CHECK(vkQueueWaitIdle(c.queue));
    return scene.finish(outPath);
}

}  // namespace

int main(int argc, char** argv) {
    if (argc == 3 && std::strcmp(argv[1], "simultaneous") == 0) return simultaneous(argv[2]);
    if (argc >= 3 && std::strcmp(argv[1], "twoqueues") == 0) {
        if (argc > 4 || (argc == 4 && std::strcmp(argv[3], "--hold-first") != 0))
            fail("unknown option");
        return twoQueues(argv[2], argc == 4);
    }
    if (argc >= 3 && std::strcmp(argv[1], "secondary") == 0) {
        bool skipBarrier = false, badClusterId = false;
        for (int i = 3; i < argc; ++i) {
            if (std::strcmp(argv[i], "--skip-barrier") == 0)
                skipBarrier = true;
            else if (std::strcmp(argv[i], "--bad-cluster-id") == 0)
                badClusterId = true;
            else
                fail("unknown option");
        }
        return secondary(argv[2], skipBarrier, badClusterId);
    }
    if (argc >= 3 && std::strcmp(argv[1], "frames") == 0) {
        FrameOptions o;
        o.frames = std::atoi(argv[2]);
        for (int i = 3; i < argc; ++i) {
            const std::string a = argv[i];
            const char* value = i + 1 < argc ? argv[i + 1] : nullptr;
            if (a == "--bad-cluster-id")
                o.badClusterId = true;
            else if (a == "--host-infos")
                o.hostInfos = true;
            else if (!value)
                fail("option without value");
            else if (a == "--clusters")
                o.clusters = uint32_t(std::atoi(argv[++i]));
            else if (a == "--out")
                o.out = argv[++i];
            else if (a == "--wait-for")
                o.waitFor = argv[++i];
            else if (a == "--exit-at")
                o.exitAt = std::atoi(argv[++i]);
            else if (a == "--abort-at")
                o.abortAt = std::atoi(argv[++i]);
            else if (a == "--stop-at")
                o.stopAt = std::atoi(argv[++i]);
            else if (a == "--race-at")
                o.raceAt = std::atoi(argv[++i]);
            else
                fail("unknown option");
        }
        if (o.frames < 1 || o.clusters < 1 || o.clusters > 4096)
            fail("frames >= 1 and clusters in [1, 4096]");
        return frames(o);
    }
    std::fprintf(
        stderr,
        "usage: capture_frames_app frames N [options] | simultaneous OUT.json | twoqueues OUT.json "
        "[--hold-first] | secondary OUT.json [--skip-barrier] [--bad-cluster-id]\n");
    return 1;
}
