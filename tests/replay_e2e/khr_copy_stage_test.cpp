// SPDX-License-Identifier: Apache-2.0
// vkCmdCopyMemoryToAccelerationStructureKHR may be synchronized with the
// ACCELERATION_STRUCTURE_COPY stage or the ACCELERATION_STRUCTURE_BUILD stage (its spec page):
// a cluster build writes the CLAS at kDst, then a deserialization overwrites that memory.
#include "catalogue_replay.h"

#include <clastrace/replay/replayer.h>

#include <gtest/gtest.h>

#include <cstring>
#include <functional>
#include <string>
#include <vector>

namespace {

using namespace clastrace;
using namespace clastrace::test;
using namespace clastrace::test::catalogue;

constexpr uint64_t kBuild = VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR;
constexpr uint64_t kAsCopy = VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_COPY_BIT_KHR;
constexpr uint64_t kAsWrite = VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR;
constexpr uint64_t kObject = 0xa5001;  // over the CLAS at kDst

// Another driver's blob: opaque, with a header that holds together (0x100 bytes serialized,
// 0x800 deserialized, no handles).
std::vector<uint8_t> foreign_blob() {
    std::vector<uint8_t> blob(0x100, 0x5a);
    const uint64_t header[3] = {0x100, 0x800, 0};
    std::memcpy(blob.data() + 32, header, sizeof header);
    return blob;
}

// The build, `order(t)` between the two commands, then the deserialization over the CLAS.
replay::ReplayReport build_then_copy(const std::string& name,
                                     const std::function<void(TraceScript&)>& order) {
    return replay_catalogue_scene(temp_trace_path("khr_copy_stage", name + ".clt"),
                                  [&](TraceScript& t) {
                                      t.acceleration_structure(kObject, kDstBuffer, 0, 0x1000);
                                      triangle_clusters(Destinations::kExplicit).emit(t);
                                      order(t);
                                      t.deserialize(kStaging, kObject, foreign_blob());
                                  });
}

// The deserialization first, then a build whose CLAS lands in the copied object's memory.
replay::ReplayReport copy_then_build(const std::string& name,
                                     const std::function<void(TraceScript&)>& order) {
    return replay_catalogue_scene(temp_trace_path("khr_copy_stage", name + ".clt"),
                                  [&](TraceScript& t) {
                                      t.acceleration_structure(kObject, kDstBuffer, 0, 0x1000);
                                      t.deserialize(kStaging, kObject, foreign_blob());
                                      order(t);
                                      triangle_clusters(Destinations::kExplicit).emit(t);
                                  });
}

std::string hazards_text(const replay::ReplayReport& r) {
    std::string s;
    for (const replay::HazardReport& h : r.hazards) s += h.format() + "\n";
    return s;
}

TEST(KhrCopyStage, WithoutBarrierTheCopyIsAHazard) {
    const replay::ReplayReport r = build_then_copy("none", [](TraceScript&) {});
    ASSERT_EQ(r.hazards.size(), 1u) << replay::format_text(r);
    EXPECT_EQ(r.hazards[0].hazard, replay::HazardClass::kDeserializeInUse);
    EXPECT_EQ(std::string(r.hazards[0].later.command.name),
              "vkCmdCopyMemoryToAccelerationStructureKHR");
}

TEST(KhrCopyStage, V1BarrierWithTheBuildStageOrdersTheCopy) {
    // vkCmdPipelineBarrier cannot name the copy stage: the build stage is the v1 form.
    const replay::ReplayReport r = build_then_copy("v1_build", [](TraceScript& t) {
        t.barrier_v1(VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                     VK_ACCESS_ACCELERATION_STRUCTURE_WRITE_BIT_KHR,
                     VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                     VK_ACCESS_ACCELERATION_STRUCTURE_WRITE_BIT_KHR);
    });
    EXPECT_TRUE(r.hazards.empty()) << hazards_text(r);
    EXPECT_TRUE(r.findings.empty()) << replay::format_text(r);
}

TEST(KhrCopyStage, Sync2BarrierWithTheCopyStageOrdersTheCopy) {
    const replay::ReplayReport r = build_then_copy("sync2_copy", [](TraceScript& t) {
        t.barrier(kBuild, kAsWrite, kAsCopy, kAsWrite);
    });
    EXPECT_TRUE(r.hazards.empty()) << hazards_text(r);
}

TEST(KhrCopyStage, Sync2BarrierWithTheBuildStageOrdersTheCopy) {
    const replay::ReplayReport r = build_then_copy("sync2_build", [](TraceScript& t) {
        t.barrier(kBuild, kAsWrite, kBuild, kAsWrite);
    });
    EXPECT_TRUE(r.hazards.empty()) << hazards_text(r);
}

TEST(KhrCopyStage, TheBuildStageAlsoOrdersWorkAfterTheCopy) {
    // The copy as the earlier command: a first scope naming the build stage takes it in.
    const replay::ReplayReport none = copy_then_build("after_none", [](TraceScript&) {});
    EXPECT_FALSE(none.hazards.empty()) << replay::format_text(none);
    const replay::ReplayReport v1 = copy_then_build("after_v1_build", [](TraceScript& t) {
        t.barrier_v1(VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                     VK_ACCESS_ACCELERATION_STRUCTURE_WRITE_BIT_KHR,
                     VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                     VK_ACCESS_ACCELERATION_STRUCTURE_WRITE_BIT_KHR);
    });
    EXPECT_TRUE(v1.hazards.empty()) << hazards_text(v1);
}

TEST(KhrCopyStage, TheCopyStageDoesNotOrderBuilds) {
    // Only the build stage stands for the copy, not the other way: a barrier from the copy
    // stage leaves the earlier build unordered.
    const replay::ReplayReport r = build_then_copy("copy_src", [](TraceScript& t) {
        t.barrier(kAsCopy, kAsWrite, kAsCopy, kAsWrite);
    });
    ASSERT_EQ(r.hazards.size(), 1u) << replay::format_text(r);
    EXPECT_EQ(r.hazards[0].hazard, replay::HazardClass::kDeserializeInUse);
}

}  // namespace
