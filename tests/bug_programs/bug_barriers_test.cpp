// SPDX-License-Identifier: Apache-2.0
// Bug programs whose two commands share a command buffer (or a batch's, or one vkCmdExecuteCommands):
// a missing, partial or misaimed barrier or event between them is a hazard naming both commands,
// the bytes and the barrier that fixes it; the variants with that barrier replay clean.
#include "bug_programs_support.h"

#include <string>

namespace clastrace::bug_programs {
namespace {

TEST_F(BugPrograms, CopiedInfosWithoutBarrierAreReadAfterWrite) {
    CAPTURE_AND_REPLAY(r, "copy_infos_no_barrier");
    EXPECT_TRUE(r.findings().empty()) << r.describe();
    ASSERT_EQ(r.hazards().size(), 1u) << r.describe();
    const json& h = r.hazards().at(0);
    EXPECT_EQ(h.at("class"), "READ-AFTER-WRITE");
    expect_side(h.at("prior"), "vkCmdCopyBuffer", 0, 0, "pRegions[0]", true);
    expect_side(h.at("later"), kClusterBuild, 0, 1, "srcInfosArray", false);
    expect_equal(range_of(h.at("overlap")), r.range("infos"));
    EXPECT_EQ(h.at("fix").at("srcStageMask"), "VK_PIPELINE_STAGE_2_COPY_BIT");
    EXPECT_EQ(h.at("fix").at("dstStageMask"),
              "VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR");
}

TEST_F(BugPrograms, CopiedInfosBehindShaderReadBufferBarrierAreReadAfterWrite) {
    CAPTURE_AND_REPLAY(r, "copy_infos_no_barrier", "--shader-read-barrier");
    EXPECT_TRUE(r.findings().empty()) << r.describe();
    ASSERT_EQ(r.hazards().size(), 1u) << r.describe();
    const json& h = r.hazards().at(0);
    EXPECT_EQ(h.at("class"), "READ-AFTER-WRITE");
    expect_side(h.at("prior"), "vkCmdCopyBuffer", 0, 0, "pRegions[0]", true);
    expect_side(h.at("later"), kClusterBuild, 0, 2, "srcInfosArray", false);
    EXPECT_EQ(h.at("later").at("access"), "INDIRECT_COMMAND_READ");
    expect_equal(range_of(h.at("overlap")), r.range("infos"));
    EXPECT_EQ(h.at("fix").at("dstAccessMask"), "VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT");
}

TEST_F(BugPrograms, CopiedInfosWithBarrierAreClean) {
    CAPTURE_AND_REPLAY(r, "copy_infos_no_barrier", "--fixed");
    expect_clean(r);
}

TEST_F(BugPrograms, VerticesUpdatedBeforeComputeStageBarrierAreReadAfterWrite) {
    CAPTURE_AND_REPLAY(r, "vertices_update_wrong_stage");
    EXPECT_TRUE(r.findings().empty()) << r.describe();
    ASSERT_EQ(r.hazards().size(), 1u) << r.describe();
    const json& h = r.hazards().at(0);
    EXPECT_EQ(h.at("class"), "READ-AFTER-WRITE");
    expect_side(h.at("prior"), "vkCmdUpdateBuffer", 0, 0, "pData", true);
    expect_side(h.at("later"), kClusterBuild, 0, 2, "srcInfosArray[1].vertexBuffer", false);
    expect_equal(range_of(h.at("overlap")), r.range("lifted"));
    EXPECT_EQ(h.at("fix").at("dstStageMask"),
              "VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR");
}

TEST_F(BugPrograms, VerticesUpdatedBeforeBuildStageBarrierAreClean) {
    CAPTURE_AND_REPLAY(r, "vertices_update_wrong_stage", "--fixed");
    expect_clean(r);
}

TEST_F(BugPrograms, SharedScratchWithoutBarrierIsWriteAfterWrite) {
    CAPTURE_AND_REPLAY(r, "shared_scratch");
    EXPECT_TRUE(r.findings().empty()) << r.describe();
    ASSERT_EQ(r.hazards().size(), 1u) << r.describe();
    const json& h = r.hazards().at(0);
    EXPECT_EQ(h.at("class"), "WRITE-AFTER-WRITE");
    expect_side(h.at("prior"), kClusterBuild, 0, 0, "scratchData", true);
    expect_side(h.at("later"), kClusterBuild, 0, 1, "scratchData", true);
    expect_inside(range_of(h.at("overlap")), r.range("scratch"));
}

TEST_F(BugPrograms, SharedScratchWithBarrierIsClean) {
    CAPTURE_AND_REPLAY(r, "shared_scratch", "--fixed");
    expect_clean(r);
}

TEST_F(BugPrograms, BottomLevelRightAfterClustersReadsUnorderedAddressesAndObjects) {
    CAPTURE_AND_REPLAY(r, "blas_same_command_buffer");
    EXPECT_TRUE(r.findings().empty()) << r.describe();
    expect_bottom_level_reads_unordered(r, 0, 0, 1, "pipeline_barrier");
}

TEST_F(BugPrograms, BottomLevelAfterBarrierIsClean) {
    CAPTURE_AND_REPLAY(r, "blas_same_command_buffer", "--fixed");
    expect_clean(r);
}

TEST_F(BugPrograms, BottomLevelAfterIndirectReadBarrierIsClean) {
    CAPTURE_AND_REPLAY(r, "blas_same_command_buffer", "--fixed-indirect");
    expect_clean(r);
}

// NVIDIA's samples order the step with acceleration-structure accesses on both sides; the
// reference array's read is taken as ordered by it (engine/execution_record.h).
TEST_F(BugPrograms, BottomLevelAfterTheSamplesStructureBarrierIsClean) {
    CAPTURE_AND_REPLAY(r, "blas_same_command_buffer", "--fixed-as-samples");
    expect_clean(r);
}

TEST_F(BugPrograms, EventWithComputeSourceStageLeavesCopiedInfosUnordered) {
    CAPTURE_AND_REPLAY(r, "event_wrong_stage");
    EXPECT_TRUE(r.findings().empty()) << r.describe();
    ASSERT_EQ(r.hazards().size(), 1u) << r.describe();
    const json& h = r.hazards().at(0);
    EXPECT_EQ(h.at("class"), "READ-AFTER-WRITE");
    expect_side(h.at("prior"), "vkCmdCopyBuffer", 0, 0, "pRegions[0]", true);
    expect_side(h.at("later"), kClusterBuild, 0, 3, "srcInfosArray", false);
    expect_equal(range_of(h.at("overlap")), r.range("infos"));
    EXPECT_NE(
        h.at("fix").at("advice").get<std::string>().find(
            "The event set between them, vkCmdSetEvent2 (queue 0, submit 0, cb 0, cmd 1), misses: "
            "its srcStageMask leaves out COPY"),
        std::string::npos)
        << h.at("fix").at("advice");
}

TEST_F(BugPrograms, EventWithCopySourceStageIsClean) {
    CAPTURE_AND_REPLAY(r, "event_wrong_stage", "--fixed");
    expect_clean(r);
}

// The build's read of the infos the copy wrote, where a buffer barrier with the right masks
// (or none over these bytes) leaves them unordered: exactly `unordered`.
void expect_infos_after_copy_unordered(const Replayed& r, Range unordered) {
    EXPECT_TRUE(r.findings().empty()) << r.describe();
    ASSERT_EQ(r.hazards().size(), 1u) << r.describe();
    const json& h = r.hazards().at(0);
    EXPECT_EQ(h.at("class"), "READ-AFTER-WRITE");
    expect_side(h.at("prior"), "vkCmdCopyBuffer", 0, 0, "pRegions[0]", true);
    expect_side(h.at("later"), kClusterBuild, 0, 2, "srcInfosArray", false);
    EXPECT_EQ(h.at("later").at("access"), "INDIRECT_COMMAND_READ");
    expect_equal(range_of(h.at("overlap")), unordered);
    EXPECT_EQ(h.at("fix").at("dstAccessMask"), "VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT");
}

TEST_F(BugPrograms, BufferBarrierOverFirstInfoLeavesTheOthersUnordered) {
    CAPTURE_AND_REPLAY(r, "barrier_wrong_range");
    expect_infos_after_copy_unordered(r, r.range("infos_past_the_barrier"));
    if (r.hazards().size() != 1) return;
    const std::string advice = r.hazards().at(0).at("fix").at("advice").get<std::string>();
    EXPECT_NE(
        advice.find(
            "vkCmdPipelineBarrier2 (queue 0, submit 0, cb 0, cmd 1), misses: its buffer range"),
        std::string::npos)
        << advice;
}

TEST_F(BugPrograms, BufferBarrierOnTheStagingBufferLeavesTheInfosUnordered) {
    CAPTURE_AND_REPLAY(r, "barrier_wrong_range", "--wrong-buffer");
    expect_infos_after_copy_unordered(r, r.range("infos"));
}

TEST_F(BugPrograms, BufferBarrierOverTheInfosIsClean) {
    CAPTURE_AND_REPLAY(r, "barrier_wrong_range", "--fixed");
    expect_clean(r);
}

// The second cluster command reads the first one's objects (templates or CLAS) through
// `field`, by the explicit addresses the first one wrote, with no barrier between.
void expect_objects_read_unordered(const Replayed& r, const std::string& field, Range objects) {
    EXPECT_TRUE(r.findings().empty()) << r.describe();
    ASSERT_EQ(r.hazards().size(), 1u) << r.describe();
    const json& h = r.hazards().at(0);
    EXPECT_EQ(h.at("class"), "READ-AFTER-WRITE");
    expect_side(h.at("prior"), kClusterBuild, 0, 0, "*dstAddressesArray", true);
    expect_side(h.at("later"), kClusterBuild, 0, 1, field, false);
    EXPECT_EQ(h.at("later").at("access"), "ACCELERATION_STRUCTURE_READ");
    expect_inside(range_of(h.at("overlap")), objects);
    EXPECT_EQ(range_of(h.at("overlap")).begin, objects.begin);
    EXPECT_EQ(h.at("fix").at("dstAccessMask"), "VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR");
}

TEST_F(BugPrograms, InstantiateRightAfterTemplateBuildReadsUnorderedTemplates) {
    CAPTURE_AND_REPLAY(r, "template_instantiate_no_barrier");
    expect_objects_read_unordered(r, "srcInfosArray[*].clusterTemplateAddress",
                                  r.range("templates"));
}

TEST_F(BugPrograms, InstantiateAfterBarrierIsClean) {
    CAPTURE_AND_REPLAY(r, "template_instantiate_no_barrier", "--fixed");
    expect_clean(r);
}

TEST_F(BugPrograms, TemplateIndicesRightAfterTemplateBuildReadUnorderedTemplates) {
    CAPTURE_AND_REPLAY(r, "template_indices_no_barrier");
    expect_objects_read_unordered(r, "srcInfosArray[*].clusterTemplateAddress",
                                  r.range("templates"));
}

TEST_F(BugPrograms, TemplateIndicesAfterBarrierAreClean) {
    CAPTURE_AND_REPLAY(r, "template_indices_no_barrier", "--fixed");
    expect_clean(r);
}

TEST_F(BugPrograms, MoveRightAfterClusterBuildReadsUnorderedClusters) {
    CAPTURE_AND_REPLAY(r, "move_after_build");
    expect_objects_read_unordered(r, "srcInfosArray[*].srcAccelerationStructure",
                                  r.range("clas_places"));
}

TEST_F(BugPrograms, MoveAfterBarrierIsClean) {
    CAPTURE_AND_REPLAY(r, "move_after_build", "--fixed");
    expect_clean(r);
}

// The command index counts the commands the trace records: the pipeline and descriptor-set
// binds and the push constants before the dispatch are state, not commands (docs/replay.md).
TEST_F(BugPrograms, InfosWrittenByDispatchWithoutBarrierAreReadAfterWrite) {
    CAPTURE_AND_REPLAY(r, "dispatch_writes_infos");
    EXPECT_TRUE(r.findings().empty()) << r.describe();
    ASSERT_EQ(r.hazards().size(), 1u) << r.describe();
    const json& h = r.hazards().at(0);
    EXPECT_EQ(h.at("class"), "READ-AFTER-WRITE");
    expect_side(h.at("prior"), "vkCmdDispatch", 0, 0, "set 0 binding 1", true);
    EXPECT_EQ(h.at("prior").at("stage"), "COMPUTE_SHADER");
    expect_side(h.at("later"), kClusterBuild, 0, 1, "srcInfosArray", false);
    expect_equal(range_of(h.at("overlap")), r.range("infos"));
    EXPECT_EQ(h.at("fix").at("srcStageMask"), "VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT");
    EXPECT_EQ(h.at("fix").at("dstAccessMask"), "VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT");
}

TEST_F(BugPrograms, InfosWrittenByDispatchBehindBarrierAreClean) {
    CAPTURE_AND_REPLAY(r, "dispatch_writes_infos", "--fixed");
    expect_clean(r);
}

// One READ-AFTER-WRITE of `field` by the build at `build_index` after the copy at
// `copy_index`, over exactly `range`, fixed by COPY/TRANSFER_WRITE -> BUILD/INDIRECT_COMMAND_READ.
const json& expect_copy_then_build_read(const Replayed& r, uint32_t copy_index,
                                        uint32_t build_index, const std::string& field,
                                        Range range) {
    EXPECT_TRUE(r.findings().empty()) << r.describe();
    EXPECT_EQ(r.hazards().size(), 1u) << r.describe();
    static const json kNone = json::object();
    if (r.hazards().empty()) return kNone;
    const json& h = r.hazards().at(0);
    EXPECT_EQ(h.at("class"), "READ-AFTER-WRITE");
    expect_side(h.at("prior"), "vkCmdCopyBuffer", 0, copy_index, "pRegions[0]", true);
    EXPECT_EQ(h.at("prior").at("stage"), "COPY");
    EXPECT_EQ(h.at("prior").at("access"), "TRANSFER_WRITE");
    expect_side(h.at("later"), kClusterBuild, 0, build_index, field, false);
    EXPECT_EQ(h.at("later").at("stage"), "ACCELERATION_STRUCTURE_BUILD");
    EXPECT_EQ(h.at("later").at("access"), "INDIRECT_COMMAND_READ");
    expect_equal(range_of(h.at("overlap")), range);
    EXPECT_EQ(h.at("fix").at("srcAccessMask"), "VK_ACCESS_2_TRANSFER_WRITE_BIT");
    EXPECT_EQ(h.at("fix").at("dstStageMask"),
              "VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR");
    EXPECT_EQ(h.at("fix").at("dstAccessMask"), "VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT");
    return h;
}

TEST_F(BugPrograms, CountCopiedFromGpuWithoutBarrierIsReadAfterWrite) {
    CAPTURE_AND_REPLAY(r, "count_written_no_barrier");
    expect_copy_then_build_read(r, 0, 1, "srcInfosCount", r.range("count"));
}

TEST_F(BugPrograms, CountCopiedFromGpuBehindBarrierIsClean) {
    CAPTURE_AND_REPLAY(r, "count_written_no_barrier", "--fixed");
    expect_clean(r);
}

TEST_F(BugPrograms, SizesCopiedForReadBackRightAfterTheBuildAreReadAfterWrite) {
    CAPTURE_AND_REPLAY(r, "sizes_readback_no_barrier");
    EXPECT_TRUE(r.findings().empty()) << r.describe();
    ASSERT_EQ(r.hazards().size(), 1u) << r.describe();
    const json& h = r.hazards().at(0);
    EXPECT_EQ(h.at("class"), "READ-AFTER-WRITE");
    expect_side(h.at("prior"), kClusterBuild, 0, 0, "dstSizesArray", true);
    EXPECT_EQ(h.at("prior").at("access"), "ACCELERATION_STRUCTURE_WRITE");
    expect_side(h.at("later"), "vkCmdCopyBuffer", 0, 1, "pRegions[0].srcOffset", false);
    EXPECT_EQ(h.at("later").at("stage"), "COPY");
    EXPECT_EQ(h.at("later").at("access"), "TRANSFER_READ");
    expect_equal(range_of(h.at("overlap")), r.range("sizes"));
    EXPECT_EQ(h.at("fix").at("srcAccessMask"), "VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR");
    EXPECT_EQ(h.at("fix").at("dstAccessMask"), "VK_ACCESS_2_TRANSFER_READ_BIT");
}

TEST_F(BugPrograms, SizesCopiedBehindBarrierAreClean) {
    CAPTURE_AND_REPLAY(r, "sizes_readback_no_barrier", "--fixed");
    expect_clean(r);
}

// The barrier is there (cmd 1) but orders execution only, or waits at TOP_OF_PIPE.
// The advice names the barrier that was there (cmd 1) and what it leaves out.
void expect_barrier_advice(const json& hazard, const std::string& barrier,
                           const std::string& missed) {
    if (hazard.empty()) return;
    const std::string advice = hazard.at("fix").at("advice").get<std::string>();
    EXPECT_NE(advice.find("The barrier between them, " + barrier +
                          " (queue 0, submit 0, cb 0, cmd 1), misses: " + missed),
              std::string::npos)
        << advice;
}

TEST_F(BugPrograms, BarrierWithoutSourceAccessLeavesCopiedInfosUnavailable) {
    CAPTURE_AND_REPLAY(r, "barrier_without_access");
    const json& h = expect_copy_then_build_read(r, 0, 2, "srcInfosArray", r.range("infos"));
    expect_barrier_advice(h, "vkCmdPipelineBarrier2",
                          "its srcAccessMask leaves out TRANSFER_WRITE");
}

TEST_F(BugPrograms, BarrierToTopOfPipeLeavesCopiedInfosUnordered) {
    CAPTURE_AND_REPLAY(r, "barrier_without_access", "--top-of-pipe");
    const json& h = expect_copy_then_build_read(r, 0, 2, "srcInfosArray", r.range("infos"));
    expect_barrier_advice(h, "vkCmdPipelineBarrier",
                          "its dstAccessMask leaves out INDIRECT_COMMAND_READ");
}

TEST_F(BugPrograms, BarrierWithAccessMasksIsClean) {
    CAPTURE_AND_REPLAY(r, "barrier_without_access", "--fixed");
    expect_clean(r);
}

TEST_F(BugPrograms, BarrierInTheNextCommandBufferOfTheBatchIsClean) {
    CAPTURE_AND_REPLAY(r, "barrier_without_access", "--fixed-split");
    expect_clean(r);
}

// Both sides run inside secondaries of one vkCmdExecuteCommands (the primary's command 0).
TEST_F(BugPrograms, SecondariesWithoutBarrierNameBothSecondaries) {
    CAPTURE_AND_REPLAY(r, "secondary_no_barrier");
    const json& h = expect_copy_then_build_read(r, 0, 0, "srcInfosArray", r.range("infos"));
    if (h.empty()) return;
    EXPECT_EQ(h.at("prior").at("secondary").at("index"), 0);
    EXPECT_EQ(h.at("prior").at("secondary").at("command_index"), 0);
    EXPECT_EQ(h.at("later").at("secondary").at("index"), 1);
    EXPECT_EQ(h.at("later").at("secondary").at("command_index"), 0);
}

TEST_F(BugPrograms, BarrierInsideTheBuildSecondaryIsClean) {
    CAPTURE_AND_REPLAY(r, "secondary_no_barrier", "--fixed");
    expect_clean(r);
}

TEST_F(BugPrograms, BarrierInThePrimaryBetweenSecondariesIsClean) {
    CAPTURE_AND_REPLAY(r, "secondary_no_barrier", "--fixed-primary");
    expect_clean(r);
}

TEST_F(BugPrograms, RebuildIntoTheStagingAreaWhileTheMoveReadsItIsWriteAfterRead) {
    CAPTURE_AND_REPLAY(r, "move_then_rebuild");
    EXPECT_TRUE(r.findings().empty()) << r.describe();
    ASSERT_EQ(r.hazards().size(), 1u) << r.describe();
    const json& h = r.hazards().at(0);
    EXPECT_EQ(h.at("class"), "WRITE-AFTER-READ");
    expect_side(h.at("prior"), kClusterBuild, 0, 2, "srcInfosArray[*].srcAccelerationStructure",
                false);
    EXPECT_EQ(h.at("prior").at("access"), "ACCELERATION_STRUCTURE_READ");
    expect_side(h.at("later"), kClusterBuild, 0, 3, "*dstAddressesArray", true);
    EXPECT_EQ(h.at("later").at("access"), "ACCELERATION_STRUCTURE_WRITE");
    expect_inside(range_of(h.at("overlap")), r.range("staged"));
    EXPECT_EQ(range_of(h.at("overlap")).begin, r.range("staged").begin);
    EXPECT_EQ(h.at("fix").at("srcStageMask"),
              "VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR");
    EXPECT_EQ(h.at("fix").at("dstStageMask"),
              "VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR");
}

TEST_F(BugPrograms, RebuildBehindBarrierAfterTheMoveIsClean) {
    CAPTURE_AND_REPLAY(r, "move_then_rebuild", "--fixed");
    expect_clean(r);
}

// The copied infos read by the build with the event's wait not covering it; the advice names
// the wait, at cmd 2, and what it leaves out.
void expect_event_wait_named(const Replayed& r, const std::string& wait,
                             const std::string& missed) {
    EXPECT_TRUE(r.findings().empty()) << r.describe();
    ASSERT_EQ(r.hazards().size(), 1u) << r.describe();
    const json& h = r.hazards().at(0);
    EXPECT_EQ(h.at("class"), "READ-AFTER-WRITE");
    expect_side(h.at("prior"), "vkCmdCopyBuffer", 0, 0, "pRegions[0]", true);
    expect_side(h.at("later"), kClusterBuild, 0, 3, "srcInfosArray", false);
    expect_equal(range_of(h.at("overlap")), r.range("infos"));
    EXPECT_NE(h.at("fix").at("advice").get<std::string>().find(
                  "The event wait between them, " + wait +
                  " (queue 0, submit 0, cb 0, cmd 2), misses: " + missed),
              std::string::npos)
        << h.at("fix").at("advice");
}

TEST_F(BugPrograms, EventWaitAtComputeStageIsNamed) {
    CAPTURE_AND_REPLAY(r, "event_wait_wrong_stage");
    expect_event_wait_named(r, "vkCmdWaitEvents2",
                            "its dstStageMask leaves out ACCELERATION_STRUCTURE_BUILD");
}

TEST_F(BugPrograms, EventWaitV1WithoutSourceAccessIsNamed) {
    CAPTURE_AND_REPLAY(r, "event_wait_wrong_stage", "--v1");
    expect_event_wait_named(r, "vkCmdWaitEvents", "its srcAccessMask leaves out TRANSFER_WRITE");
}

TEST_F(BugPrograms, EventWaitAtBuildStageIsClean) {
    CAPTURE_AND_REPLAY(r, "event_wait_wrong_stage", "--fixed");
    expect_clean(r);
}

TEST_F(BugPrograms, EventWaitV1WithSourceAccessIsClean) {
    CAPTURE_AND_REPLAY(r, "event_wait_wrong_stage", "--v1 --fixed");
    expect_clean(r);
}

TEST_F(BugPrograms, CountOverwrittenRightAfterTheBuildIsWriteAfterRead) {
    CAPTURE_AND_REPLAY(r, "count_overwritten_after_build");
    EXPECT_TRUE(r.findings().empty()) << r.describe();
    ASSERT_EQ(r.hazards().size(), 1u) << r.describe();
    const json& h = r.hazards().at(0);
    EXPECT_EQ(h.at("class"), "WRITE-AFTER-READ");
    expect_side(h.at("prior"), kClusterBuild, 0, 0, "srcInfosCount", false);
    expect_side(h.at("later"), "vkCmdCopyBuffer", 0, 1, "pRegions[0]", true);
    expect_equal(range_of(h.at("overlap")), r.range("count"));
    EXPECT_EQ(h.at("fix").at("srcStageMask"),
              "VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR");
    EXPECT_EQ(h.at("fix").at("dstStageMask"), "VK_PIPELINE_STAGE_2_COPY_BIT");
}

TEST_F(BugPrograms, CountOverwrittenBehindExecutionBarrierIsClean) {
    CAPTURE_AND_REPLAY(r, "count_overwritten_after_build", "--fixed");
    expect_clean(r);
}

// Session 17: a fill ordered from COPY, an indirect count ordered for DRAW_INDIRECT, a buffer
// barrier over a strided array sized as if packed.
TEST_F(BugPrograms, FilledCountBehindCopyStageBarrierIsReadAfterWrite) {
    CAPTURE_AND_REPLAY(r, "fill_count_copy_stage");
    EXPECT_TRUE(r.findings().empty()) << r.describe();
    ASSERT_EQ(r.hazards().size(), 1u) << r.describe();
    const json& h = r.hazards().at(0);
    EXPECT_EQ(h.at("class"), "READ-AFTER-WRITE");
    expect_side(h.at("prior"), "vkCmdFillBuffer", 0, 0, "dstOffset", true);
    EXPECT_EQ(h.at("prior").at("stage"), "CLEAR");
    expect_side(h.at("later"), kClusterBuild, 0, 2, "srcInfosCount", false);
    expect_equal(range_of(h.at("overlap")), r.range("count"));
    EXPECT_EQ(h.at("fix").at("srcStageMask"), "VK_PIPELINE_STAGE_2_CLEAR_BIT");
    EXPECT_NE(h.at("fix").at("advice").get<std::string>().find(
                  "vkCmdPipelineBarrier2 (queue 0, submit 0, cb 0, cmd 1), misses: its "
                  "srcStageMask leaves out CLEAR"),
              std::string::npos)
        << h.at("fix").at("advice");
}

TEST_F(BugPrograms, FilledCountBehindClearStageBarrierIsClean) {
    CAPTURE_AND_REPLAY(r, "fill_count_copy_stage", "--fixed");
    expect_clean(r);
}

TEST_F(BugPrograms, FilledCountBehindAllTransferBarrierIsClean) {
    CAPTURE_AND_REPLAY(r, "fill_count_copy_stage", "--all-transfer");
    expect_clean(r);
}

// Synchronization 1's TRANSFER stage holds the clear commands.
TEST_F(BugPrograms, FilledCountBehindTransferStageBarrierV1IsClean) {
    CAPTURE_AND_REPLAY(r, "fill_count_copy_stage", "--v1");
    expect_clean(r);
}

TEST_F(BugPrograms, DispatchedCountBehindDrawIndirectBarrierIsReadAfterWrite) {
    CAPTURE_AND_REPLAY(r, "count_dispatch_draw_indirect");
    EXPECT_TRUE(r.findings().empty()) << r.describe();
    ASSERT_EQ(r.hazards().size(), 1u) << r.describe();
    const json& h = r.hazards().at(0);
    EXPECT_EQ(h.at("class"), "READ-AFTER-WRITE");
    expect_side(h.at("prior"), "vkCmdDispatch", 0, 0, "set 0 binding 1", true);
    expect_side(h.at("later"), kClusterBuild, 0, 2, "srcInfosCount", false);
    expect_equal(range_of(h.at("overlap")), r.range("count"));
    EXPECT_EQ(h.at("fix").at("dstStageMask"),
              "VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR");
    EXPECT_NE(h.at("fix").at("advice").get<std::string>().find(
                  "its dstStageMask leaves out ACCELERATION_STRUCTURE_BUILD"),
              std::string::npos)
        << h.at("fix").at("advice");
}

TEST_F(BugPrograms, DispatchedCountBehindBuildStageBarrierIsClean) {
    CAPTURE_AND_REPLAY(r, "count_dispatch_draw_indirect", "--fixed");
    expect_clean(r);
}

// The advice names the records' barrier (the one nearest the bytes), not the objects' one of
// the same vkCmdPipelineBarrier2.
TEST_F(BugPrograms, StridedAddressesBehindPackedSizeBarrierAreReadAfterWrite) {
    CAPTURE_AND_REPLAY(r, "strided_addresses_barrier_short");
    EXPECT_TRUE(r.findings().empty()) << r.describe();
    ASSERT_EQ(r.hazards().size(), 1u) << r.describe();
    const json& h = r.hazards().at(0);
    EXPECT_EQ(h.at("class"), "READ-AFTER-WRITE");
    expect_side(h.at("prior"), kClusterBuild, 0, 0, "dstAddressesArray", true);
    expect_side(h.at("later"), kClusterBuild, 0, 2, "srcInfosArray[0].clusterReferences", false);
    const Range uncovered = r.range("uncovered");
    const Range overlap = range_of(h.at("overlap"));
    EXPECT_EQ(overlap.begin, uncovered.begin);     // record 2's address
    EXPECT_EQ(overlap.end, uncovered.begin + 24);  // to record 3's address's end
    const Range records = r.range("records");
    char covered[64];
    std::snprintf(covered, sizeof covered, "[0x%llx, 0x%llx)",
                  static_cast<unsigned long long>(records.begin),
                  static_cast<unsigned long long>(uncovered.begin));
    EXPECT_NE(h.at("fix").at("advice").get<std::string>().find(
                  std::string("misses: its buffer range ") + covered + " leaves these bytes out"),
              std::string::npos)
        << h.at("fix").at("advice");
}

TEST_F(BugPrograms, StridedAddressesBehindWholeSizeBarrierAreClean) {
    CAPTURE_AND_REPLAY(r, "strided_addresses_barrier_short", "--fixed");
    expect_clean(r);
}

}  // namespace
}  // namespace clastrace::bug_programs
