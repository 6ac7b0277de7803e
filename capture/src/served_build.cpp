#include "clastrace/capture/served_build.h"

#include "clastrace/capture/cluster_limits.h"

#include <clastrace/engine/build_sizes.h>
#include <clastrace/engine/execute.h>

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <exception>

namespace clastrace::capture {
namespace {

std::string hex(uint64_t v) {
  char text[24];
  std::snprintf(text, sizeof text, "0x%llx", (unsigned long long)v);
  return text;
}

}  // namespace

ServedExecution executeServedBuild(const VkClusterAccelerationStructureCommandsInfoNV& command,
                                   std::span<const ServedBuffer> buffers, engine::ObjectDirectory& directory,
                                   const engine::EngineProperties& properties) {
  ServedExecution result;
  std::vector<const ServedBuffer*> sorted;
  for (const ServedBuffer& b : buffers)
    if (b.address != 0 && b.size != 0 && b.host && b.address + b.size > b.address) sorted.push_back(&b);
  std::sort(sorted.begin(), sorted.end(), [](auto* a, auto* b) { return a->address < b->address; });

  engine::MemoryImage image;
  try {
    // Aliases share addresses: one region per run of overlapping buffers, their usages joined.
    for (size_t first = 0; first < sorted.size();) {
      uint64_t end = sorted[first]->address + sorted[first]->size;
      VkBufferUsageFlags usage = sorted[first]->usage;
      size_t last = first + 1;
      for (; last < sorted.size() && sorted[last]->address < end; ++last) {
        end = std::max(end, sorted[last]->address + sorted[last]->size);
        usage |= sorted[last]->usage;
      }
      const uint64_t base = sorted[first]->address;
      engine::MemoryRegion& region = image.add_region(base, end - base, usage, "buffer " + hex(sorted[first]->buffer));
      for (size_t i = first; i < last; ++i) {
        std::memcpy(region.bytes.data() + (sorted[i]->address - base), sorted[i]->host, sorted[i]->size);
        result.bytesCopiedIn += sorted[i]->size;
      }
      first = last;
    }
    engine::ExecuteOptions options;
    options.properties = properties;
    options.directory = &directory;
    result.record = engine::execute(command, image, options);
  } catch (const std::exception& e) {
    result.error = e.what();
    return result;
  }
  result.ran = true;

  // Back into every buffer that holds a written byte (aliases included: same memory or not,
  // each view must show what the command wrote).
  for (const engine::MemoryAccess& access : result.record.accesses) {
    if (!access.is_write || access.end <= access.begin) continue;
    for (const ServedBuffer* b : sorted) {
      const uint64_t begin = std::max(access.begin, b->address);
      const uint64_t end = std::min(access.end, b->address + b->size);
      if (begin >= end) continue;
      const engine::MemoryRegion* region = image.find_region(begin);
      if (!region || end > region->base + region->size) continue;  // the engine wrote only inside regions
      std::memcpy(b->host + (begin - b->address), region->bytes.data() + (begin - region->base), end - begin);
      result.bytesWrittenBack += end - begin;
      if (std::find(result.writtenMemories.begin(), result.writtenMemories.end(), b->memory) ==
          result.writtenMemories.end())
        result.writtenMemories.push_back(b->memory);
    }
  }
  return result;
}

bool servedClusterBuildSizes(const VkClusterAccelerationStructureInputInfoNV& input,
                             VkAccelerationStructureBuildSizesInfoKHR& sizes) {
  const engine::BuildSizes answer = engine::cluster_build_sizes(input, servedEngineProperties());
  sizes.accelerationStructureSize = answer.acceleration_structure_size;
  sizes.buildScratchSize = answer.build_scratch_size;
  sizes.updateScratchSize = answer.update_scratch_size;
  return answer.findings.empty();
}

}  // namespace clastrace::capture
