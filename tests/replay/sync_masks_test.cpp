// SPDX-License-Identifier: Apache-2.0
#include <gtest/gtest.h>

#include "clastrace/replay/sync_masks.h"

namespace clastrace::replay {
namespace {

TEST(SyncMasks, SourceScopeAddsLogicallyEarlierStages) {
    const StageMask compute = source_scope(VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT);
    EXPECT_TRUE(compute & VK_PIPELINE_STAGE_2_DRAW_INDIRECT_BIT);
    EXPECT_TRUE(compute & VK_PIPELINE_STAGE_2_CONDITIONAL_RENDERING_BIT_EXT);
    EXPECT_FALSE(compute & VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR);
    // Nothing is logically earlier or later than the AS build stage, but it also names the
    // acceleration-structure copy stage (the KHR copy may be synchronized with either; its
    // spec page says so); the copy stage does not name the build stage.
    const StageMask build_and_copy = VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR |
                                     VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_COPY_BIT_KHR;
    EXPECT_EQ(source_scope(VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR),
              build_and_copy);
    EXPECT_EQ(destination_scope(VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR),
              build_and_copy);
    EXPECT_FALSE(source_scope(VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_COPY_BIT_KHR) &
                 VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR);
}

TEST(SyncMasks, DestinationScopeAddsLogicallyLaterStages) {
    const StageMask indirect = destination_scope(VK_PIPELINE_STAGE_2_DRAW_INDIRECT_BIT);
    EXPECT_TRUE(indirect & VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT);
    EXPECT_TRUE(indirect & VK_PIPELINE_STAGE_2_RAY_TRACING_SHADER_BIT_KHR);
    EXPECT_TRUE(indirect & VK_PIPELINE_STAGE_2_FRAGMENT_SHADER_BIT);
    EXPECT_FALSE(indirect & VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR);
    EXPECT_FALSE(indirect & VK_PIPELINE_STAGE_2_COPY_BIT);
    const StageMask vs = destination_scope(VK_PIPELINE_STAGE_2_VERTEX_SHADER_BIT);
    EXPECT_TRUE(vs & VK_PIPELINE_STAGE_2_COLOR_ATTACHMENT_OUTPUT_BIT);
    EXPECT_FALSE(vs & VK_PIPELINE_STAGE_2_DRAW_INDIRECT_BIT);
}

TEST(SyncMasks, TopAndBottomOfPipe) {
    EXPECT_EQ(source_scope(VK_PIPELINE_STAGE_2_TOP_OF_PIPE_BIT), 0u);
    EXPECT_EQ(destination_scope(VK_PIPELINE_STAGE_2_BOTTOM_OF_PIPE_BIT), 0u);
    EXPECT_EQ(source_scope(VK_PIPELINE_STAGE_2_BOTTOM_OF_PIPE_BIT), all_device_stages());
    EXPECT_EQ(destination_scope(VK_PIPELINE_STAGE_2_TOP_OF_PIPE_BIT), all_device_stages());
    EXPECT_EQ(source_scope(VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT), all_device_stages());
    // Host work is not a device command.
    EXPECT_FALSE(all_device_stages() & VK_PIPELINE_STAGE_2_HOST_BIT);
}

TEST(SyncMasks, AggregatesExpand) {
    const StageMask transfer = atomic_stages(VK_PIPELINE_STAGE_2_ALL_TRANSFER_BIT);
    EXPECT_EQ(transfer, VK_PIPELINE_STAGE_2_COPY_BIT | VK_PIPELINE_STAGE_2_BLIT_BIT |
                            VK_PIPELINE_STAGE_2_RESOLVE_BIT | VK_PIPELINE_STAGE_2_CLEAR_BIT |
                            VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_COPY_BIT_KHR);
    EXPECT_EQ(atomic_stages(VK_PIPELINE_STAGE_2_VERTEX_INPUT_BIT),
              VK_PIPELINE_STAGE_2_INDEX_INPUT_BIT | VK_PIPELINE_STAGE_2_VERTEX_ATTRIBUTE_INPUT_BIT);
    EXPECT_FALSE(atomic_stages(VK_PIPELINE_STAGE_2_ALL_GRAPHICS_BIT) &
                 VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT);
    const AccessMask reads = atomic_accesses(VK_ACCESS_2_MEMORY_READ_BIT);
    EXPECT_TRUE(reads & VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT);
    EXPECT_TRUE(reads & VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR);
    EXPECT_FALSE(reads & VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR);
    EXPECT_FALSE(reads & VK_ACCESS_2_MEMORY_READ_BIT);
    const AccessMask writes = atomic_accesses(VK_ACCESS_2_MEMORY_WRITE_BIT);
    EXPECT_TRUE(writes & VK_ACCESS_2_TRANSFER_WRITE_BIT);
    EXPECT_TRUE(writes & VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT);
    EXPECT_FALSE(writes & VK_ACCESS_2_SHADER_WRITE_BIT);
    EXPECT_EQ(atomic_accesses(VK_ACCESS_2_SHADER_READ_BIT),
              VK_ACCESS_2_SHADER_SAMPLED_READ_BIT | VK_ACCESS_2_SHADER_STORAGE_READ_BIT);
    EXPECT_TRUE(has_write(VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR));
    EXPECT_FALSE(has_write(VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT));
}

TEST(SyncMasks, V1MasksAreTheLowBitsOfV2) {
    EXPECT_EQ(stages_from_v1(VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR),
              VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR);
    EXPECT_EQ(stages_from_v1(VK_PIPELINE_STAGE_TRANSFER_BIT), VK_PIPELINE_STAGE_2_ALL_TRANSFER_BIT);
    EXPECT_EQ(accesses_from_v1(VK_ACCESS_ACCELERATION_STRUCTURE_WRITE_BIT_KHR),
              VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR);
}

TEST(SyncMasks, Names) {
    EXPECT_EQ(stage_names(VK_PIPELINE_STAGE_2_COPY_BIT |
                          VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR),
              "ACCELERATION_STRUCTURE_BUILD|COPY");
    EXPECT_EQ(stage_flag_names(VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR),
              "VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR");
    EXPECT_EQ(access_flag_names(VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT),
              "VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT");
    EXPECT_EQ(access_flag_names(0), "VK_ACCESS_2_NONE");
    EXPECT_EQ(access_names(0), "NONE");
    EXPECT_EQ(stage_names(StageMask(1) << 60), "0x1000000000000000");  // unknown bits stay visible
}

}  // namespace
}  // namespace clastrace::replay
