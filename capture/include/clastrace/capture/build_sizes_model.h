// Answers vkGetClusterAccelerationStructureBuildSizesNV while the layer serves the extension.
//
// PLACEHOLDER FOR THE ENGINE'S SIZE MODEL. These are upper bounds derived only from the input
// limits, never exact sizes of what a driver or our engine would build; the engine's size model
// replaces this function once it exists (engine issue: whole-command execution).
#pragma once

#include <clastrace/vk_cluster_abi.h>

namespace clastrace::capture {

// Fills accelerationStructureSize, buildScratchSize and updateScratchSize (0: no updates).
// Returns false (and zero sizes) for an input the model rejects (null op input, unknown op).
bool conservativeClusterBuildSizes(const VkClusterAccelerationStructureInputInfoNV& input,
                                   const VkPhysicalDeviceClusterAccelerationStructurePropertiesNV& limits,
                                   VkAccelerationStructureBuildSizesInfoKHR& sizes);

}  // namespace clastrace::capture
