// SPDX-License-Identifier: Apache-2.0
// Bug programs of VK_KHR_acceleration_structure (lavapipe 25; they skip on drivers without it):
// builds, copies, deserializes and property queries with no barrier between them.
#include "bug_programs_support.h"

#include <string>

namespace clastrace::bug_programs {
namespace {

// Needs VK_KHR_acceleration_structure (lavapipe 25): skips on drivers without it.
TEST_F(BugPrograms, KhrTopLevelRightAfterItsBottomLevelIsReadAfterWrite) {
    CAPTURE_AND_REPLAY(r, "khr_tlas_without_barrier");
    EXPECT_TRUE(r.findings().empty()) << r.describe();
    ASSERT_EQ(r.hazards().size(), 1u) << r.describe();
    const json& h = r.hazards().at(0);
    EXPECT_EQ(h.at("class"), "READ-AFTER-WRITE");
    const std::string build = "vkCmdBuildAccelerationStructuresKHR";
    expect_side(h.at("prior"), build, 0, 0, "pInfos[0].dstAccelerationStructure", true);
    expect_side(
        h.at("later"), build, 0, 1,
        "pInfos[0].pGeometries[0].geometry.instances.data[0].accelerationStructureReference",
        false);
    EXPECT_EQ(h.at("later").at("access"), "ACCELERATION_STRUCTURE_READ");
    expect_equal(range_of(h.at("overlap")), r.range("bottom_level"));
}

TEST_F(BugPrograms, KhrTopLevelAfterBarrierIsClean) {
    CAPTURE_AND_REPLAY(r, "khr_tlas_without_barrier", "--fixed");
    expect_clean(r);
}

// Needs VK_KHR_acceleration_structure (lavapipe 25): skips on drivers without it.
TEST_F(BugPrograms, KhrInstancesCopiedWithoutBarrierAreReadAfterWrite) {
    CAPTURE_AND_REPLAY(r, "khr_instances_copy_no_barrier");
    EXPECT_TRUE(r.findings().empty()) << r.describe();
    ASSERT_EQ(r.hazards().size(), 1u) << r.describe();
    const json& h = r.hazards().at(0);
    EXPECT_EQ(h.at("class"), "READ-AFTER-WRITE");
    expect_side(h.at("prior"), "vkCmdCopyBuffer", 1, 0, "pRegions[0]", true);
    expect_side(h.at("later"), "vkCmdBuildAccelerationStructuresKHR", 1, 1,
                "pInfos[0].pGeometries[0].geometry.instances.data", false);
    EXPECT_EQ(h.at("later").at("access"), "SHADER_READ");
    expect_equal(range_of(h.at("overlap")), r.range("instances"));
}

TEST_F(BugPrograms, KhrInstancesCopiedBehindBarrierAreClean) {
    CAPTURE_AND_REPLAY(r, "khr_instances_copy_no_barrier", "--fixed");
    expect_clean(r);
}

TEST_F(BugPrograms, KhrBottomLevelsSharingScratchWithoutBarrierAreWriteAfterWrite) {
    CAPTURE_AND_REPLAY(r, "khr_shared_scratch");
    EXPECT_TRUE(r.findings().empty()) << r.describe();
    ASSERT_EQ(r.hazards().size(), 1u) << r.describe();
    const json& h = r.hazards().at(0);
    EXPECT_EQ(h.at("class"), "WRITE-AFTER-WRITE");
    const std::string build = "vkCmdBuildAccelerationStructuresKHR";
    expect_side(h.at("prior"), build, 0, 0, "pInfos[0].scratchData", true);
    expect_side(h.at("later"), build, 0, 1, "pInfos[0].scratchData", true);
    expect_inside(range_of(h.at("overlap")), r.range("scratch"));
}

TEST_F(BugPrograms, KhrBottomLevelsSharingScratchBehindBarrierAreClean) {
    CAPTURE_AND_REPLAY(r, "khr_shared_scratch", "--fixed");
    expect_clean(r);
}

// The blob is lavapipe's serialized form, which the engine cannot decode: the replay lists
// that among its notes (not findings), and still orders the deserialize's read of the blob.
TEST_F(BugPrograms, KhrDeserializeRightAfterTheBlobCopyIsReadAfterWrite) {
    CAPTURE_AND_REPLAY(r, "khr_deserialize_no_barrier");
    EXPECT_TRUE(r.findings().empty()) << r.describe();
    ASSERT_EQ(r.hazards().size(), 1u) << r.describe();
    const json& h = r.hazards().at(0);
    EXPECT_EQ(h.at("class"), "READ-AFTER-WRITE");
    expect_side(h.at("prior"), "vkCmdCopyBuffer", 3, 0, "pRegions[0]", true);
    expect_side(h.at("later"), "vkCmdCopyMemoryToAccelerationStructureKHR", 3, 1, "pInfo->src",
                false);
    EXPECT_EQ(h.at("later").at("access"), "TRANSFER_READ");
    expect_equal(range_of(h.at("overlap")), r.range("blob"));
    EXPECT_EQ(h.at("fix").at("srcStageMask"), "VK_PIPELINE_STAGE_2_COPY_BIT");
}

TEST_F(BugPrograms, KhrDeserializeBehindBarrierIsClean) {
    CAPTURE_AND_REPLAY(r, "khr_deserialize_no_barrier", "--fixed");
    expect_clean(r);
}

// Needs VK_KHR_acceleration_structure (lavapipe 25). The engine's compacted size differs from
// lavapipe's by design: a note, not a finding.
TEST_F(BugPrograms, KhrCompactedSizeQueryRightAfterTheBuildIsReadAfterWrite) {
    CAPTURE_AND_REPLAY(r, "khr_compacted_size_no_barrier");
    EXPECT_TRUE(r.findings().empty()) << r.describe();
    ASSERT_EQ(r.hazards().size(), 1u) << r.describe();
    const json& h = r.hazards().at(0);
    EXPECT_EQ(h.at("class"), "READ-AFTER-WRITE");
    expect_side(h.at("prior"), "vkCmdBuildAccelerationStructuresKHR", 0, 0,
                "pInfos[0].dstAccelerationStructure", true);
    expect_side(h.at("later"), "vkCmdWriteAccelerationStructuresPropertiesKHR", 0, 1,
                "pAccelerationStructures[0]", false);
    EXPECT_EQ(h.at("later").at("stage"), "ACCELERATION_STRUCTURE_BUILD");
    EXPECT_EQ(h.at("later").at("access"), "ACCELERATION_STRUCTURE_READ");
    expect_equal(range_of(h.at("overlap")), r.range("bottom_level"));
    EXPECT_EQ(h.at("fix").at("dstAccessMask"), "VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR");
}

TEST_F(BugPrograms, KhrCompactedSizeQueryBehindBarrierIsClean) {
    CAPTURE_AND_REPLAY(r, "khr_compacted_size_no_barrier", "--fixed");
    expect_clean(r);
}

}  // namespace
}  // namespace clastrace::bug_programs
