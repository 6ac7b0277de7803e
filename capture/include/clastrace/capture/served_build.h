// Executing a served vkCmdBuildClusterAccelerationStructureIndirectNV with clastrace's engine,
// and answering vkGetClusterAccelerationStructureBuildSizesNV from the engine's size model.
//
// The layer calls executeServedBuild at the pause before the command, while the queue waits:
// the host bytes of the addressed buffers it reaches become the engine's MemoryImage, the engine runs
// the whole command, and every range its ExecutionRecord marks written is copied back into
// those host bytes. Vulkan specifics (mapping, flush/invalidate) stay with the caller.
#pragma once

#include "clastrace/capture/capture_records.h"

#include <clastrace/engine/execution_record.h>
#include <clastrace/engine/memory_image.h>
#include <clastrace/engine/object_directory.h>
#include <clastrace/engine/properties.h>
#include <clastrace/vk_cluster_abi.h>

#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

namespace clastrace::capture {

// One buffer the command may touch, through the host's view of its bytes.
struct ServedBuffer {
  uint64_t buffer = 0;
  VkDeviceAddress address = 0;
  VkDeviceSize size = 0;
  VkBufferUsageFlags usage = 0;
  uint8_t* host = nullptr;  // the first byte of the buffer in host memory
  uint64_t memory = 0;      // the allocation, so the caller can flush what was written
};

struct ServedExecution {
  bool ran = false;                        // false: the engine could not start (see `error`)
  std::string error;
  engine::ExecutionRecord record;
  std::vector<uint64_t> writtenMemories;   // allocations that received bytes (to flush)
  uint64_t bytesCopiedIn = 0, bytesWrittenBack = 0;  // of the last attempt
  uint32_t attempts = 0;  // engine runs until the image held every buffer the command reads
  // The image of the last run, holding every byte the command read and wrote, as it left it:
  // the capture reads the command's outputs from it after the queue was released.
  std::shared_ptr<const engine::MemoryImage> image;
};

// Buffers whose address ranges overlap (aliases) become one region holding their union. Only
// the buffers the command reaches are copied: those it names, then those its findings point
// into, found by running again; the result equals a run over all of `buffers`. `inputWalk`:
// the command's inputs as the capture already walked them at this pause (saves walking twice),
// or null.
ServedExecution executeServedBuild(const VkClusterAccelerationStructureCommandsInfoNV& command,
                                   std::span<const ServedBuffer> buffers, engine::ObjectDirectory& directory,
                                   const engine::EngineProperties& properties,
                                   const std::vector<CapturedRange>* inputWalk = nullptr);

// vkGetClusterAccelerationStructureBuildSizesNV of the served device: engine::cluster_build_sizes.
// False (and zero sizes) when the engine rejects the input (its findings say why).
bool servedClusterBuildSizes(const VkClusterAccelerationStructureInputInfoNV& input,
                             VkAccelerationStructureBuildSizesInfoKHR& sizes);

}  // namespace clastrace::capture
