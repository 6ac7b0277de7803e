// SPDX-License-Identifier: Apache-2.0
// The served device's answers come from the engine: build sizes equal engine::cluster_build_sizes
// and hold a real build; executeServedBuild writes back exactly what engine::execute computes.
#include "clastrace/capture/cluster_input_walker.h"
#include "clastrace/capture/cluster_limits.h"
#include "clastrace/capture/served_build.h"
#include "served_scene.h"

#include <clastrace/engine/build_sizes.h>
#include <clastrace/engine/cluster_format.h>
#include <clastrace/engine/execute.h>

#include <gtest/gtest.h>

#include <algorithm>
#include <cstring>
#include <map>

using namespace clastrace;
using namespace clastrace::capture;

namespace {

// The scene's buffers in host memory, at made-up device addresses 64 KiB apart.
struct HostScene {
    served_scene::Addresses a;
    served_scene::Commands commands;
    std::map<std::string, std::vector<uint8_t>> bytes;
    std::vector<ServedBuffer> buffers;
    VkAccelerationStructureBuildSizesInfoKHR clusterSizes{}, blasSizes{};

    HostScene() {
        served_scene::Commands sizing;
        served_scene::makeCommands({}, sizing);
        EXPECT_TRUE(served_cluster_build_sizes(sizing.clusters.input, clusterSizes));
        EXPECT_TRUE(served_cluster_build_sizes(sizing.blas.input, blasSizes));
        served_scene::Inputs probe = served_scene::makeInputs({});
        uint64_t next = 0x100000;
        auto add = [&](const char* name, uint64_t& address, uint64_t size,
                       VkBufferUsageFlags usage) {
            address = next;
            next += (size + 0xFFFF) / 0x10000 * 0x10000 + 0x10000;
            bytes[name].assign(size, 0xEE);
            buffers.push_back({buffers.size() + 1, address, size, usage, nullptr, 7});
        };
        const VkBufferUsageFlags in =
            VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR;
        const VkBufferUsageFlags st = VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR;
        const VkBufferUsageFlags sc = VK_BUFFER_USAGE_STORAGE_BUFFER_BIT;
        add("vertices", a.vertices, probe.vertices.size() * 4, in);
        add("indices", a.indices, probe.indices.size() * 4, in);
        add("infos", a.infos, served_scene::kInfoStride * served_scene::kMaxClusters, in);
        add("counts", a.counts, 8, in);
        add("dstAddresses", a.dstAddresses, 8 * served_scene::kMaxClusters, st | in);
        add("dstSizes", a.dstSizes, 4 * served_scene::kMaxClusters, st);
        add("implicitData", a.implicitData, clusterSizes.accelerationStructureSize, st);
        add("scratch", a.scratch, clusterSizes.buildScratchSize, sc);
        add("blasInfos", a.blasInfos,
            sizeof(VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV), in);
        add("blasDstAddresses", a.blasDstAddresses, 8, st);
        add("blasDstSizes", a.blasDstSizes, 4, st);
        add("blasImplicit", a.blasImplicit, blasSizes.accelerationStructureSize, st);
        add("blasScratch", a.blasScratch, blasSizes.buildScratchSize, sc);
        size_t i = 0;
        for (auto name : {"vertices", "indices", "infos", "counts", "dstAddresses", "dstSizes",
                          "implicitData", "scratch", "blasInfos", "blasDstAddresses",
                          "blasDstSizes", "blasImplicit", "blasScratch"})
            buffers[i++].host = bytes[name].data();
        served_scene::Inputs inputs = served_scene::makeInputs(a);
        std::memcpy(bytes["vertices"].data(), inputs.vertices.data(), inputs.vertices.size() * 4);
        std::memcpy(bytes["indices"].data(), inputs.indices.data(), inputs.indices.size() * 4);
        std::memcpy(bytes["infos"].data(), inputs.infos.data(),
                    inputs.infos.size() * served_scene::kInfoStride);
        std::memcpy(bytes["counts"].data(), inputs.counts, 8);
        std::memcpy(bytes["blasInfos"].data(), &inputs.blasInfo, sizeof inputs.blasInfo);
        served_scene::makeCommands(a, commands);
    }
    template <class T>
    T at(const char* name, size_t index) {
        T value;
        std::memcpy(&value, bytes.at(name).data() + index * sizeof(T), sizeof(T));
        return value;
    }
};

}  // namespace

TEST(ServedBuild, LimitsAreTheEngines) {
    const auto served = served_cluster_properties();
    const auto engine = engine::EngineProperties::nvidia_default().to_vk();
    EXPECT_EQ(served.sType,
              VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_CLUSTER_ACCELERATION_STRUCTURE_PROPERTIES_NV);
    EXPECT_EQ(served.clusterByteAlignment, engine.clusterByteAlignment);
    EXPECT_EQ(served.clusterBottomLevelByteAlignment, engine.clusterBottomLevelByteAlignment);
    EXPECT_EQ(served.maxTrianglesPerCluster, engine.maxTrianglesPerCluster);
    EXPECT_EQ(served.maxClusterGeometryIndex, engine.maxClusterGeometryIndex);
}

TEST(ServedBuild, BuildSizesAreTheEnginesAndHoldARealBuild) {
    HostScene scene;
    for (auto* command : {&scene.commands.clusters, &scene.commands.blas}) {
        const engine::BuildSizes want =
            engine::cluster_build_sizes(command->input, served_engine_properties());
        VkAccelerationStructureBuildSizesInfoKHR got{};
        ASSERT_TRUE(served_cluster_build_sizes(command->input, got));
        EXPECT_EQ(got.accelerationStructureSize, want.acceleration_structure_size);
        EXPECT_EQ(got.buildScratchSize, want.build_scratch_size);
        EXPECT_EQ(got.updateScratchSize, 0u);
    }
    engine::ObjectDirectory directory;
    for (auto [command, sizes] : {std::pair{&scene.commands.clusters, scene.clusterSizes},
                                  std::pair{&scene.commands.blas, scene.blasSizes}}) {
        ServedExecution run =
            execute_served_build(*command, scene.buffers, directory, served_engine_properties());
        ASSERT_TRUE(run.ran) << run.error;
        EXPECT_TRUE(run.record.findings.empty())
            << run.record.findings[0].rule << ": " << run.record.findings[0].message;
        EXPECT_GT(run.record.implicit_bytes_used, 0u);
        EXPECT_LE(run.record.implicit_bytes_used, sizes.accelerationStructureSize);
        EXPECT_LE(run.record.scratch_bytes_used, sizes.buildScratchSize);
    }
}

TEST(ServedBuild, RejectedInputAnswersZero) {
    VkClusterAccelerationStructureInputInfoNV input{};
    input.maxAccelerationStructureCount = 1;
    input.opType = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV;
    VkAccelerationStructureBuildSizesInfoKHR sizes{};
    sizes.accelerationStructureSize = 5;
    EXPECT_FALSE(served_cluster_build_sizes(input, sizes));  // no op input
    EXPECT_EQ(sizes.accelerationStructureSize, 0u);
}

// What lands in the host bytes is exactly what engine::execute writes into a MemoryImage of
// the same buffers; the bottom level reads the addresses the cluster build wrote.
TEST(ServedBuild, WritesBackExactlyWhatTheEngineWrote) {
    HostScene scene;
    engine::MemoryImage image;
    for (const ServedBuffer& b : scene.buffers) {
        auto& region = image.add_region(b.address, b.size, b.usage, "");
        std::memcpy(region.bytes.data(), b.host, b.size);
    }
    engine::ObjectDirectory served, direct;
    engine::ExecuteOptions options;
    options.directory = &direct;
    for (auto* command : {&scene.commands.clusters, &scene.commands.blas}) {
        ServedExecution run =
            execute_served_build(*command, scene.buffers, served, served_engine_properties());
        ASSERT_TRUE(run.ran) << run.error;
        EXPECT_EQ(run.written_memories, std::vector<uint64_t>{7});
        engine::execute(*command, image, options);
    }
    for (const ServedBuffer& b : scene.buffers) {
        auto want = image.read_bytes(b.address, b.size, {});
        EXPECT_EQ(std::memcmp(want.data(), b.host, b.size), 0) << "buffer " << b.buffer;
    }
    const auto properties = served_cluster_properties();
    for (uint32_t i = 0; i < served_scene::kClusterCount; ++i) {
        const uint64_t address = scene.at<uint64_t>("dstAddresses", i);
        const uint32_t size = scene.at<uint32_t>("dstSizes", i);
        EXPECT_GT(size, 0u);
        EXPECT_EQ(address % properties.clusterByteAlignment, 0u);
        ASSERT_GE(address, scene.a.implicitData);
        ASSERT_LE(address + size,
                  scene.a.implicitData + scene.clusterSizes.accelerationStructureSize);
        uint32_t magic;
        std::memcpy(&magic, scene.bytes["implicitData"].data() + (address - scene.a.implicitData),
                    4);
        EXPECT_EQ(magic, engine::kObjectMagic);
    }
    EXPECT_EQ(scene.at<uint32_t>("dstSizes", served_scene::kClusterCount),
              0xEEEEEEEEu);  // not an op: untouched
    const uint64_t blas = scene.at<uint64_t>("blasDstAddresses", 0);
    EXPECT_EQ(blas % properties.clusterBottomLevelByteAlignment, 0u);
    EXPECT_GT(scene.at<uint32_t>("blasDstSizes", 0), 0u);
    EXPECT_EQ(blas, scene.a.blasImplicit);
}

// Aliasing buffers (same addresses) become one region; each alias receives the written bytes.
TEST(ServedBuild, AliasedBuffersAreOneRegionAndAllReceiveTheWrites) {
    HostScene scene;
    std::vector<uint8_t> alias(scene.bytes["dstSizes"]);
    scene.buffers.push_back(
        {99, scene.a.dstSizes, alias.size(), VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, alias.data(), 8});
    engine::ObjectDirectory directory;
    ServedExecution run = execute_served_build(scene.commands.clusters, scene.buffers, directory,
                                               served_engine_properties());
    ASSERT_TRUE(run.ran) << run.error;
    EXPECT_TRUE(run.record.findings.empty());
    EXPECT_EQ(std::memcmp(alias.data(), scene.bytes["dstSizes"].data(), alias.size()), 0);
    EXPECT_GT(scene.at<uint32_t>("dstSizes", 0), 0u);
    EXPECT_NE(scene.at<uint32_t>("dstSizes", 0), 0xEEEEEEEEu);
}

// Addresses outside every buffer: the engine reports them, nothing is written, no crash.
TEST(ServedBuild, MissingMemoryBecomesFindingsNotACrash) {
    HostScene scene;
    std::vector<ServedBuffer> none;
    engine::ObjectDirectory directory;
    ServedExecution run =
        execute_served_build(scene.commands.clusters, none, directory, served_engine_properties());
    ASSERT_TRUE(run.ran) << run.error;
    EXPECT_FALSE(run.record.findings.empty());
    EXPECT_EQ(run.bytes_written_back, 0u);
}

// Only the buffers the command reaches are copied: a large unrelated buffer is left alone, and
// the result still equals engine::execute over all memory (checked above with every buffer).
TEST(ServedBuild, CopiesOnlyTheBuffersTheCommandReaches) {
    HostScene scene;
    std::vector<uint8_t> unrelated(1 << 20, 0x5A);
    scene.buffers.push_back({77, 0x40000000, unrelated.size(), VK_BUFFER_USAGE_STORAGE_BUFFER_BIT,
                             unrelated.data(), 9});
    uint64_t sceneBytes = 0;
    for (const auto& [name, bytes] : scene.bytes) sceneBytes += bytes.size();
    engine::ObjectDirectory directory;
    ServedExecution clusters = execute_served_build(scene.commands.clusters, scene.buffers,
                                                    directory, served_engine_properties());
    ASSERT_TRUE(clusters.ran) << clusters.error;
    EXPECT_TRUE(clusters.record.findings.empty());
    EXPECT_EQ(clusters.attempts, 1u);  // the pointer walk named the index and vertex buffers
    EXPECT_LT(clusters.bytes_copied_in, sceneBytes);
    // The bottom level: the walk names the reference array and the clusters it lists.
    ServedExecution blas = execute_served_build(scene.commands.blas, scene.buffers, directory,
                                                served_engine_properties());
    ASSERT_TRUE(blas.ran) << blas.error;
    EXPECT_TRUE(blas.record.findings.empty()) << blas.record.findings[0].message;
    EXPECT_EQ(blas.attempts, 1u);
    EXPECT_LT(blas.bytes_copied_in, sceneBytes);
    EXPECT_GT(scene.at<uint32_t>("blasDstSizes", 0), 0u);
    EXPECT_EQ(std::count(unrelated.begin(), unrelated.end(), 0x5A), long(unrelated.size()));
}

// A command with a finding no buffer explains runs once more over every buffer, so what it
// reports and writes is what a run over all memory gives.
TEST(ServedBuild, UnexplainedFindingsRunOverAllBuffers) {
    HostScene scene;
    uint64_t allBytes = 0;
    for (const auto& b : scene.buffers) allBytes += b.size;
    scene.commands.clusters.scratchData = 0;  // VUID-...-scratchData-12300
    engine::ObjectDirectory directory;
    ServedExecution run = execute_served_build(scene.commands.clusters, scene.buffers, directory,
                                               served_engine_properties());
    ASSERT_TRUE(run.ran) << run.error;
    EXPECT_TRUE(engine::has_rule(run.record.findings, engine::kRuleScratchTooSmall));
    EXPECT_EQ(run.bytes_copied_in, allBytes);
}

// What the walk does not follow (move sources) is found by running again: the first run's
// finding about the source cluster adds the buffer holding it.
TEST(ServedBuild, BuffersTheWalkMissesAreFoundByRunningAgain) {
    HostScene scene;
    engine::ObjectDirectory directory;
    ASSERT_TRUE(execute_served_build(scene.commands.clusters, scene.buffers, directory,
                                     served_engine_properties())
                    .ran);
    const uint64_t source = scene.at<uint64_t>("dstAddresses", 1);
    const uint32_t sourceSize = scene.at<uint32_t>("dstSizes", 1);

    VkClusterAccelerationStructureMoveObjectsInputNV moveInput{};
    moveInput.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_MOVE_OBJECTS_INPUT_NV;
    moveInput.type = VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_TRIANGLE_CLUSTER_NV;
    moveInput.noMoveOverlap = VK_TRUE;
    moveInput.maxMovedBytes = 1 << 16;
    VkClusterAccelerationStructureCommandsInfoNV move{};
    move.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV;
    move.input.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_INPUT_INFO_NV;
    move.input.maxAccelerationStructureCount = 1;
    move.input.opType = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV;
    move.input.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
    move.input.opInput.pMoveObjects = &moveInput;
    VkAccelerationStructureBuildSizesInfoKHR sizes{};
    ASSERT_TRUE(served_cluster_build_sizes(move.input, sizes));
    std::vector<uint8_t> info(8), count(4), dstAddress(8), dstSize(4),
        dst(sizes.accelerationStructureSize),
        scratch(std::max<uint64_t>(sizes.buildScratchSize, 16));
    std::memcpy(info.data(), &source, 8);
    count[0] = 1;
    const VkBufferUsageFlags in =
        VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR;
    const VkBufferUsageFlags st = VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR;
    std::vector<ServedBuffer> buffers = scene.buffers;
    buffers.push_back({201, 0x7000000, info.size(), in, info.data(), 7});
    buffers.push_back({202, 0x7100000, count.size(), in, count.data(), 7});
    buffers.push_back({203, 0x7200000, dstAddress.size(), st, dstAddress.data(), 7});
    buffers.push_back({204, 0x7300000, dstSize.size(), st, dstSize.data(), 7});
    buffers.push_back({205, 0x7400000, dst.size(), st, dst.data(), 7});
    buffers.push_back(
        {206, 0x7500000, scratch.size(), VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, scratch.data(), 7});
    move.srcInfosArray = {0x7000000, 8, 8};
    move.srcInfosCount = 0x7100000;
    move.dstAddressesArray = {0x7200000, 8, 8};
    move.dstSizesArray = {0x7300000, 4, 4};
    move.dstImplicitData = 0x7400000;
    move.scratchData = 0x7500000;

    ServedExecution run =
        execute_served_build(move, buffers, directory, served_engine_properties());
    ASSERT_TRUE(run.ran) << run.error;
    EXPECT_TRUE(run.record.findings.empty()) << run.record.findings[0].message;
    EXPECT_EQ(run.attempts, 2u);
    uint32_t movedSize;
    std::memcpy(&movedSize, dstSize.data(), 4);
    EXPECT_EQ(movedSize, sourceSize);
    EXPECT_EQ(std::memcmp(dst.data(),
                          scene.bytes["implicitData"].data() + (source - scene.a.implicitData),
                          sourceSize),
              0);
}

// Frame after frame from one pool: each frame's images reuse the last one's region bytes (no
// fresh mapping), yet every run sees the host bytes as they are now, not what the reused pages
// held, and writes back exactly what a run without the pool writes.
TEST(ServedBuild, RegionPoolReusesBytesAndNeverLeaksStaleOnes) {
    HostScene pooled, plain;
    auto pool = std::make_shared<ServedRegionPool>();
    engine::ObjectDirectory pooledDirectory, plainDirectory;
    for (int frame = 0; frame < 3; ++frame) {
        for (HostScene* scene : {&pooled, &plain}) {  // the vertices move every frame
            float* v = reinterpret_cast<float*>(scene->bytes["vertices"].data());
            for (size_t i = 0; i < scene->bytes["vertices"].size() / 4; i += 3)
                v[i] += 0.25f * float(frame + 1);
        }
        for (auto command : {&served_scene::Commands::clusters, &served_scene::Commands::blas}) {
            const uint64_t heldBefore = pool->held_bytes();
            ServedMemory memory(pooled.buffers, pool);
            // (0: the completion walks no more entries than the engine ran)
            ServedExecution a =
                execute_served_build(pooled.commands.*command, memory, pooledDirectory,
                                     served_engine_properties(), nullptr, 0u);
            ServedExecution b = execute_served_build(plain.commands.*command, plain.buffers,
                                                     plainDirectory, served_engine_properties());
            ASSERT_TRUE(a.ran && b.ran) << a.error << b.error;
            if (command == &served_scene::Commands::clusters) {
                // The inputs went back to the pool as the build ended, while its image lives on for the
                // record's completion with the outputs only: after the first frame, with the same bytes.
                EXPECT_EQ(a.image->find_region(pooled.a.vertices), nullptr)
                    << "frame " << frame << ": inputs kept";
                // Without output entries nobody walks the image later: it stays whole.
                EXPECT_NE(b.image->find_region(plain.a.vertices), nullptr) << "frame " << frame;
                EXPECT_NE(a.image->find_region(pooled.a.implicitData), nullptr)
                    << "frame " << frame;
                EXPECT_NE(a.image->find_region(pooled.a.dstSizes), nullptr) << "frame " << frame;
                EXPECT_GE(pool->held_bytes(),
                          pooled.bytes["vertices"].size() + pooled.bytes["indices"].size());
                if (frame > 0) {
                    EXPECT_LE(pool->held_bytes(), heldBefore)
                        << "frame " << frame << ": fresh bytes taken";
                }
            }
        }  // the images go back to the pool here
        for (const char* name :
             {"implicitData", "dstAddresses", "dstSizes", "blasImplicit", "blasDstSizes"})
            EXPECT_EQ(pooled.bytes[name], plain.bytes[name]) << name << ", frame " << frame;
    }
    EXPECT_GT(pool->held_bytes(), 0u);
    EXPECT_LE(pool->held_bytes(), ServedRegionPool::kMaxBytes);
}

TEST(ServedBuild, RegionPoolMatchesExactSizesAndStaysBounded) {
    ServedRegionPool pool;
    EXPECT_TRUE(pool.take(4096).empty());
    std::vector<engine::RegionBytes> given;
    given.emplace_back(8192);
    given.emplace_back(ServedRegionPool::kMaxBytes);  // does not fit beside the first
    pool.give(std::move(given));
    EXPECT_EQ(pool.held_bytes(), 8192u);
    EXPECT_TRUE(pool.take(4096).empty());
    engine::RegionBytes back = pool.take(8192);
    EXPECT_EQ(back.size(), 8192u);
    EXPECT_EQ(pool.held_bytes(), 0u);
}

// Between pauses the pool makes ready, pages faulted in, as many regions of each size as one
// of the last pauses took (while records waiting to be written hold theirs), and no more; a
// size no longer taken drops out of the demand after kDemandPauses pauses.
TEST(ServedBuild, RegionPoolMakesReadyWhatTheLastPausesTook) {
    ServedRegionPool pool;
    EXPECT_FALSE(pool.make_one_ready());  // no demand yet
    EXPECT_TRUE(pool.take(8192).empty());
    EXPECT_TRUE(pool.take(8192).empty());
    EXPECT_TRUE(pool.take(4096).empty());
    EXPECT_FALSE(pool.make_one_ready());  // the pause has not ended
    pool.pause_ended();
    int made = 0;
    while (pool.make_one_ready()) ++made;
    EXPECT_EQ(made, 3);
    EXPECT_EQ(pool.held_bytes(), 2 * 8192u + 4096u);
    engine::RegionBytes lent = pool.take(8192);
    ASSERT_EQ(lent.size(), 8192u);
    EXPECT_EQ(lent.resident_bytes(), 8192u);  // faulted in: the copy into it faults no page
    EXPECT_EQ(std::to_integer<int>(lent.data()[4096]), 0);
    pool.pause_ended();  // took one 8192: the demand is still two of them
    EXPECT_TRUE(pool.make_one_ready());
    EXPECT_FALSE(pool.make_one_ready());
    // Pauses taking only 4096 push the 8192s out of the demand, not out of the pool.
    for (size_t i = 0; i < ServedRegionPool::kDemandPauses; ++i) {
        engine::RegionBytes small = pool.take(4096);
        pool.pause_ended();
        std::vector<engine::RegionBytes> back;
        back.push_back(std::move(small));
        pool.give(std::move(back));
    }
    EXPECT_FALSE(pool.make_one_ready());
    EXPECT_EQ(pool.held_bytes(), 2 * 8192u + 4096u);
}

// The capture's walk and the served build read through one copy: a read copies the buffer's
// alias group on first touch only, and ranges outside every buffer, or across two, are null.
TEST(ServedBuild, ServedMemoryCopiesAGroupOnFirstRead) {
    std::vector<uint8_t> a(4096, 1), b(4096, 2), c(100, 3);
    const std::vector<ServedBuffer> buffers = {
        {1, 0x10000, 4096, 0, a.data(), 7, false},  // uncached: streaming loads
        {2, 0x10800, 4096, 0, b.data(), 7, true},   // aliases the second half of the first
        {3, 0x40000, 100, 0, c.data(), 8, true},
    };
    ServedMemory memory(buffers);
    ASSERT_EQ(memory.groups().size(), 2u);
    EXPECT_EQ(memory.bytes_copied(), 0u);
    const uint8_t* p = memory.read(0x10000, 16);
    ASSERT_NE(p, nullptr);
    EXPECT_EQ(p[0], 1);
    EXPECT_EQ(memory.bytes_copied(), 8192u);    // both buffers of the group, once
    EXPECT_EQ(memory.read(0x10800, 16)[0], 2);  // the later buffer's bytes where they alias
    EXPECT_EQ(memory.bytes_copied(), 8192u);
    EXPECT_FALSE(memory.copied(1));
    EXPECT_EQ(memory.read(0x40000 + 90, 20), nullptr);  // runs past the buffer
    EXPECT_EQ(memory.read(0x30000, 4), nullptr);
    EXPECT_EQ(memory.buffer_holding(0x10900, 16)->buffer, 2u);
    EXPECT_EQ(memory.buffer_holding(0x10100, 16)->buffer, 1u);
    EXPECT_EQ(memory.buffer_holding(0x107F8, 16)->buffer, 1u);  // only the first holds all of it

    // A small buffer inside a large one: past its end only the large one holds a range (the
    // small one's end minus the address must not wrap into "holds").
    std::vector<uint8_t> large(0x10000, 4), small(0x100, 5);
    const std::vector<ServedBuffer> nested = {{1, 0x100000, 0x10000, 0, large.data(), 7, true},
                                              {2, 0x100800, 0x100, 0, small.data(), 7, true}};
    ServedMemory inside(nested);
    EXPECT_EQ(inside.buffer_holding(0x105000, 16)->buffer, 1u);
    EXPECT_EQ(inside.buffer_holding(0x100810, 16)->buffer, 2u);
    EXPECT_EQ(inside.read(0x100810, 4)[0], 5);
    EXPECT_EQ(inside.read(0x105000, 4)[0], 4);  // after a read of the small one (the cached buffer)
    EXPECT_EQ(inside.read(0x10F000, 0x2000), nullptr);
}

// A served record is completed off the pause worker: its outputs come from the engine's image
// of the run (equal to what was written back to the application), every range is named by the
// pause's buffer holding it, and a range no buffer holds stays unnamed.
TEST(ServedBuild, CompletedRecordHoldsTheWrittenOutputsNamedByThePausesBuffers) {
    HostScene scene;
    ServedMemory memory(scene.buffers);
    engine::ObjectDirectory directory;
    ServedExecution run =
        execute_served_build(scene.commands.clusters, memory, directory, served_engine_properties(),
                             nullptr, served_scene::kClusterCount);
    ASSERT_TRUE(run.ran) << run.error;
    ClusterBuildCapture record;
    record.executed_count = served_scene::kClusterCount;
    record.inputs.push_back({MemoryRole::kVertexBuffer, 0, scene.a.vertices + 12, {1, 2, 3}});
    record.inputs.push_back({MemoryRole::kVertexBuffer, 0, 0x7FFF0000, {4}});  // in no buffer
    const ClusterCommandParameters parameters =
        ClusterCommandParameters::copy_of(scene.commands.clusters);
    complete_served_record(record, run.image, parameters, memory);
    EXPECT_TRUE(record.issues.empty()) << record.issues[0].rule;
    EXPECT_EQ(record.inputs[0].buffer, 1u);  // "vertices", the scene's first buffer
    EXPECT_EQ(record.inputs[0].buffer_offset, 12u);
    EXPECT_EQ(record.inputs[1].buffer, 0u);
    std::map<MemoryRole, size_t> roles;
    for (const CapturedRange& r : record.outputs) {
        ++roles[r.role];
        const ServedBuffer* holder = memory.buffer_holding(r.address, r.bytes.size());
        ASSERT_NE(holder, nullptr) << memory_role_name(r.role);
        EXPECT_EQ(r.buffer, holder->buffer);
        EXPECT_EQ(r.buffer_offset, r.address - holder->address);
        EXPECT_EQ(std::memcmp(r.bytes.data(), holder->host + r.buffer_offset, r.bytes.size()), 0)
            << memory_role_name(r.role) << ": not what was written back";
    }
    EXPECT_EQ(roles[MemoryRole::kDstAddresses], 1u);
    EXPECT_EQ(roles[MemoryRole::kDstSizes], 1u);
    EXPECT_EQ(roles[MemoryRole::kDstObject], size_t(served_scene::kClusterCount));
}

// The completed outputs are views into the engine's image, not copies: they stay valid (and
// equal to what was written back) after every other owner let the image go, and the image's
// bytes return to the region pool only when the record itself is freed.
TEST(ServedBuild, CompletedOutputsViewTheImageAndKeepItUntilTheRecordGoes) {
    HostScene scene;
    auto pool = std::make_shared<ServedRegionPool>();
    engine::ObjectDirectory directory;
    uint64_t poolWhileHeld = 0;
    {
        ClusterBuildCapture record;
        {
            ServedMemory memory(scene.buffers, pool);
            ServedExecution run = execute_served_build(scene.commands.clusters, memory, directory,
                                                       served_engine_properties(), nullptr,
                                                       served_scene::kClusterCount);
            ASSERT_TRUE(run.ran) << run.error;
            record.executed_count = served_scene::kClusterCount;
            complete_served_record(record, std::move(run.image),
                                   ClusterCommandParameters::copy_of(scene.commands.clusters),
                                   memory);
        }  // the run, its memory and the caller's reference to the image are gone
        poolWhileHeld = pool->held_bytes();
        ASSERT_FALSE(record.outputs.empty());
        uint64_t viewed = 0;
        for (const CapturedRange& r : record.outputs) {
            EXPECT_TRUE(r.bytes.is_view()) << memory_role_name(r.role);
            EXPECT_EQ(r.bytes.owned_size(), 0u);
            viewed += r.bytes.size();
            const ServedBuffer* holder = nullptr;
            for (const ServedBuffer& b : scene.buffers)
                if (b.buffer == r.buffer) holder = &b;
            ASSERT_NE(holder, nullptr) << memory_role_name(r.role);
            EXPECT_EQ(std::memcmp(r.bytes.data(), holder->host + r.buffer_offset, r.bytes.size()),
                      0)
                << memory_role_name(r.role) << ": the view no longer shows what was written back";
        }
        EXPECT_GT(viewed, 0u);
    }  // the record and with it the last view
    EXPECT_GT(pool->held_bytes(), poolWhileHeld)
        << "the image did not return to the pool with the record";
}

// The capture's input walk views the image the engine then runs on. Where the build writes
// over bytes it read (here its dst sizes land on its own first src infos), the captured
// inputs still hold what it read, taken from the application's memory before the write-back;
// ranges the build did not write stay views, and their groups stay in the shared image.
TEST(ServedBuild, InputViewsTheBuildWritesOverKeepWhatItRead) {
    HostScene scene;
    for (ServedBuffer& b : scene.buffers)
        if (b.address == scene.a.infos)
            b.usage |= VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR;
    VkClusterAccelerationStructureCommandsInfoNV command = scene.commands.clusters;
    command.dstSizesArray.deviceAddress = scene.a.infos;
    const std::vector<uint8_t> infosBefore = scene.bytes["infos"],
                               verticesBefore = scene.bytes["vertices"];

    ServedMemory memory(scene.buffers);
    DeviceMemoryReader read = [&](VkDeviceAddress a, uint64_t s, CapturedBytes* o,
                                  std::string& why) {
        if (memory.view(a, s, o)) return true;
        why = "not served";
        return false;
    };
    ClusterMemoryWalk walk = walk_cluster_inputs(ClusterCommandParameters::copy_of(command), read);
    ASSERT_TRUE(walk.issues.empty()) << walk.issues[0].rule;
    engine::ObjectDirectory directory;
    ServedExecution run =
        execute_served_build(command, memory, directory, served_engine_properties(), &walk.ranges,
                             walk.executed_count);
    ASSERT_TRUE(run.ran) << run.error;
    ASSERT_NE(scene.bytes["infos"], infosBefore)
        << "the build did not write over its src infos: nothing tested";

    size_t infos = 0, vertexViews = 0;
    for (const CapturedRange& r : walk.ranges) {
        const std::vector<uint8_t>* before = r.role == MemoryRole::kSrcInfos       ? &infosBefore
                                             : r.role == MemoryRole::kVertexBuffer ? &verticesBefore
                                                                                   : nullptr;
        if (!before) continue;
        const uint64_t base = r.role == MemoryRole::kSrcInfos ? scene.a.infos : scene.a.vertices;
        ASSERT_LE(r.address - base + r.bytes.size(), before->size());
        EXPECT_EQ(std::memcmp(r.bytes.data(), before->data() + (r.address - base), r.bytes.size()),
                  0)
            << memory_role_name(r.role) << " at +" << (r.address - base)
            << ": not what the build read";
        if (r.role == MemoryRole::kSrcInfos) {
            ++infos;
            EXPECT_FALSE(r.bytes.is_view()) << "a written-over range stayed a view";
        } else {
            vertexViews += r.bytes.is_view();
        }
    }
    EXPECT_GT(infos, 0u);
    EXPECT_GT(vertexViews, 0u) << "ranges the build did not write should stay views";
    // (Its findings about the aliasing made the engine run again over every buffer, in a fresh
    // image: the views kept the first one, which the test's checks above read through.)
    EXPECT_GT(run.attempts, 1u);
}

// A build that writes none of its inputs: every input range the walk took from the image
// stays a view, their groups stay in the shared image (while the outputs-only reduction
// still drops the groups nobody views), and all of it returns to the pool with the last view.
TEST(ServedBuild, InputViewsKeepTheirGroupsInTheSharedImage) {
    HostScene scene;
    auto pool = std::make_shared<ServedRegionPool>();
    std::vector<CapturedRange> inputs;
    {
        ServedMemory memory(scene.buffers, pool);
        DeviceMemoryReader read = [&](VkDeviceAddress a, uint64_t s, CapturedBytes* o,
                                      std::string& why) {
            if (memory.view(a, s, o)) return true;
            why = "not served";
            return false;
        };
        ClusterMemoryWalk walk =
            walk_cluster_inputs(ClusterCommandParameters::copy_of(scene.commands.clusters), read);
        ASSERT_TRUE(walk.issues.empty()) << walk.issues[0].rule;
        memory.copy(
            memory.group_of(scene.a.blasInfos));  // read, not viewed: the reduction drops it
        engine::ObjectDirectory directory;
        ServedExecution run =
            execute_served_build(scene.commands.clusters, memory, directory,
                                 served_engine_properties(), &walk.ranges, walk.executed_count);
        ASSERT_TRUE(run.ran) << run.error;
        EXPECT_EQ(run.attempts, 1u);
        for (const CapturedRange& r : walk.ranges)
            EXPECT_TRUE(r.bytes.views(run.image.get())) << memory_role_name(r.role);
        EXPECT_NE(run.image->find_region(scene.a.vertices), nullptr);
        EXPECT_NE(run.image->find_region(scene.a.indices), nullptr);
        EXPECT_EQ(run.image->find_region(scene.a.blasInfos), nullptr);
        inputs = std::move(walk.ranges);
    }
    const uint64_t whileViewed = pool->held_bytes();
    inputs.clear();
    EXPECT_GE(pool->held_bytes(),
              whileViewed + scene.bytes["vertices"].size() + scene.bytes["indices"].size());
}

// With explicit destinations the build reads dstSizesArray (the spec's
// VkClusterAccelerationStructureCommandsInfoNV::dstSizesArray): the record holds the sizes the
// application wrote as an input, as read at execution, and not as an output (the engine writes
// none there). Without it replay saw zeros there and reported every destination too small.
TEST(ServedBuild, ExplicitDestinationSizesAreRecordedAsRead) {
    HostScene scene;
    VkClusterAccelerationStructureCommandsInfoNV command = scene.commands.clusters;
    command.input.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV;
    VkAccelerationStructureBuildSizesInfoKHR one{};
    VkClusterAccelerationStructureInputInfoNV oneInput = command.input;
    oneInput.maxAccelerationStructureCount = 1;
    ASSERT_TRUE(served_cluster_build_sizes(oneInput, one));
    const uint64_t slot = (one.accelerationStructureSize + 255) / 256 * 256;
    ASSERT_LE(served_scene::kClusterCount * slot, scene.bytes["implicitData"].size());
    for (uint32_t i = 0; i < served_scene::kClusterCount; ++i) {
        const uint64_t address = scene.a.implicitData + i * slot;
        const uint32_t size = uint32_t(one.accelerationStructureSize);
        std::memcpy(scene.bytes["dstAddresses"].data() + 8 * i, &address, 8);
        std::memcpy(scene.bytes["dstSizes"].data() + 4 * i, &size, 4);
    }

    ServedMemory memory(scene.buffers);
    DeviceMemoryReader read = [&](VkDeviceAddress a, uint64_t s, CapturedBytes* o,
                                  std::string& why) {
        if (memory.view(a, s, o)) return true;
        why = "not served";
        return false;
    };
    ClusterMemoryWalk walk = walk_cluster_inputs(ClusterCommandParameters::copy_of(command), read);
    ASSERT_TRUE(walk.issues.empty()) << walk.issues[0].rule;
    engine::ObjectDirectory directory;
    ServedExecution run =
        execute_served_build(command, memory, directory, served_engine_properties(), &walk.ranges,
                             walk.executed_count);
    ASSERT_TRUE(run.ran) << run.error;
    EXPECT_TRUE(run.record.findings.empty())
        << run.record.findings[0].rule << ": " << run.record.findings[0].message;
    ClusterBuildCapture record;
    record.executed_count = walk.executed_count;
    record.inputs = std::move(walk.ranges);
    complete_served_record(record, std::move(run.image), ClusterCommandParameters::copy_of(command),
                           memory);

    std::vector<const CapturedRange*> sizesRead;
    for (const CapturedRange& r : record.inputs)
        if (r.role == MemoryRole::kDstSizes) sizesRead.push_back(&r);
    ASSERT_EQ(sizesRead.size(), 1u) << "dstSizesArray is not among the inputs";
    EXPECT_EQ(sizesRead[0]->address, scene.a.dstSizes);
    ASSERT_EQ(sizesRead[0]->bytes.size(), 4u * served_scene::kClusterCount);
    EXPECT_EQ(std::memcmp(sizesRead[0]->bytes.data(), scene.bytes["dstSizes"].data(),
                          4u * served_scene::kClusterCount),
              0);
    size_t objects = 0;
    for (const CapturedRange& r : record.outputs) {
        EXPECT_NE(r.role, MemoryRole::kDstSizes) << "dstSizesArray recorded as written";
        EXPECT_NE(r.role, MemoryRole::kDstAddresses) << "dstAddressesArray recorded as written";
        if (r.role == MemoryRole::kDstObject) {
            EXPECT_EQ(r.bytes.size(), one.accelerationStructureSize);
            ++objects;
        }
    }
    EXPECT_EQ(objects, served_scene::kClusterCount);
}
