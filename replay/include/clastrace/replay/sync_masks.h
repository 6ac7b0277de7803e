// SPDX-License-Identifier: Apache-2.0
// Pipeline stage and access masks as the synchronization model sees them.
//
// Masks are Vulkan's synchronization2 flags (VkPipelineStageFlags2 / VkAccessFlags2).
// Synchronization-1 masks carry over unchanged: every v1 bit has the same value in v2.
// Before the model compares masks it "normalizes" them: aggregate bits (ALL_COMMANDS,
// ALL_TRANSFER, SHADER_READ, MEMORY_WRITE, ...) become the atomic bits they stand for,
// and stage masks are widened by the spec's logically-earlier (source) or
// logically-later (destination) stages.
#pragma once

#include <cstdint>
#include <string>

#include <vulkan/vulkan_core.h>

namespace clastrace::replay {

using StageMask = VkPipelineStageFlags2;
using AccessMask = VkAccessFlags2;

// Atomic (non-aggregate) device stages, host excluded.
StageMask all_device_stages();
// Atomic stages of `mask` (aggregates expanded, TOP/BOTTOM dropped). HOST stays HOST.
StageMask atomic_stages(StageMask mask);
// First synchronization scope of a source stage mask: atomic stages plus every logically
// earlier stage (BOTTOM_OF_PIPE = ALL_COMMANDS, TOP_OF_PIPE = NONE). Both scopes take
// ACCELERATION_STRUCTURE_COPY in with ACCELERATION_STRUCTURE_BUILD: the copy commands may be
// synchronized with either stage (vkCmdCopyMemoryToAccelerationStructureKHR).
StageMask source_scope(StageMask mask);
// Second synchronization scope of a destination stage mask: atomic stages plus every
// logically later stage (TOP_OF_PIPE = ALL_COMMANDS, BOTTOM_OF_PIPE = NONE).
StageMask destination_scope(StageMask mask);

// Atomic accesses of `mask`: MEMORY_READ/MEMORY_WRITE/SHADER_READ/SHADER_WRITE expanded.
AccessMask atomic_accesses(AccessMask mask);
AccessMask all_read_accesses();
AccessMask all_write_accesses();
bool has_write(AccessMask mask);

// v1 masks are the low 32 bits of the v2 masks (the spec assigns identical values).
inline StageMask stages_from_v1(VkPipelineStageFlags v1) { return StageMask(v1); }
inline AccessMask accesses_from_v1(VkAccessFlags v1) { return AccessMask(v1); }

// "COPY|ACCELERATION_STRUCTURE_BUILD" (short form, as sync hazard messages print).
std::string stage_names(StageMask mask);
std::string access_names(AccessMask mask);
// "VK_PIPELINE_STAGE_2_COPY_BIT|VK_PIPELINE_STAGE_2_..." (the names code would use).
std::string stage_flag_names(StageMask mask);
std::string access_flag_names(AccessMask mask);

}  // namespace clastrace::replay
