#include "clastrace/capture/served_build.h"

#include "clastrace/capture/cluster_input_walker.h"
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

namespace {

// Buffers whose address ranges overlap (aliases), as the one region they form in the image.
struct AliasGroup {
  uint64_t base = 0, end = 0;
  VkBufferUsageFlags usage = 0;
  std::vector<const ServedBuffer*> buffers;
};

std::vector<AliasGroup> aliasGroups(std::span<const ServedBuffer> buffers) {
  std::vector<const ServedBuffer*> sorted;
  for (const ServedBuffer& b : buffers)
    if (b.address != 0 && b.size != 0 && b.host && b.address + b.size > b.address) sorted.push_back(&b);
  std::sort(sorted.begin(), sorted.end(), [](auto* a, auto* b) { return a->address < b->address; });
  std::vector<AliasGroup> groups;
  for (const ServedBuffer* b : sorted) {
    if (groups.empty() || b->address >= groups.back().end) groups.push_back({b->address, b->address, 0, {}});
    AliasGroup& g = groups.back();
    g.end = std::max(g.end, b->address + b->size);
    g.usage |= b->usage;
    g.buffers.push_back(b);
  }
  return groups;
}

// Index of the group holding `address`, or groups.size().
size_t groupOf(const std::vector<AliasGroup>& groups, uint64_t address) {
  auto it = std::upper_bound(groups.begin(), groups.end(), address, [](uint64_t a, const AliasGroup& g) { return a < g.base; });
  if (it == groups.begin()) return groups.size();
  --it;
  return address < it->end ? size_t(it - groups.begin()) : groups.size();
}

}  // namespace

ServedExecution executeServedBuild(const VkClusterAccelerationStructureCommandsInfoNV& command,
                                   std::span<const ServedBuffer> buffers, engine::ObjectDirectory& directory,
                                   const engine::EngineProperties& properties,
                                   const std::vector<CapturedRange>* inputWalk) {
  ServedExecution result;
  const std::vector<AliasGroup> groups = aliasGroups(buffers);

  // Start from the buffers the command names itself and those its pointers lead to; run; every
  // finding about an address in a buffer left out adds that buffer, and the command runs again
  // from the same state (the directory is copied per attempt). A run without findings read only
  // memory that was there, so it equals a run over all buffers. With findings left, or with
  // indirected fields (whose targets the seeds do not name), the last run is over all buffers:
  // exact either way.
  std::vector<bool> selected(groups.size(), false);
  auto select = [&](uint64_t address) {
    const size_t g = address ? groupOf(groups, address) : groups.size();
    if (g == groups.size() || selected[g]) return false;
    selected[g] = true;
    return true;
  };
  if (command.addressResolutionFlags != 0) {
    selected.assign(groups.size(), true);
  } else {
    for (uint64_t seed : {command.srcInfosArray.deviceAddress, command.srcInfosCount, command.dstImplicitData,
                          command.scratchData, command.dstAddressesArray.deviceAddress,
                          command.dstSizesArray.deviceAddress})
      select(seed);
    // The capture's pointer walk names most of the rest (index, vertex, geometry, reference
    // arrays; the clusters a reference array names), so one engine run usually suffices.
    DeviceMemoryReader read = [&](VkDeviceAddress address, uint64_t size, std::vector<uint8_t>* out, std::string& why) {
      const size_t g = groupOf(groups, address);
      if (g < groups.size())
        for (const ServedBuffer* b : groups[g].buffers)
          if (address >= b->address && size <= b->address + b->size - address) {
            if (out) out->assign(b->host + (address - b->address), b->host + (address - b->address) + size);
            return true;
          }
      why = "not inside one buffer";
      return false;
    };
    ClusterMemoryWalk walk;
    if (!inputWalk) walk = walkClusterInputs(ClusterCommandParameters::copyOf(command), read);
    for (const CapturedRange& range : inputWalk ? *inputWalk : walk.ranges) {
      select(range.address);
      if (range.role != MemoryRole::ClusterReferences) continue;
      for (size_t at = 0; at + 8 <= range.bytes.size(); at += 8) {
        uint64_t reference;
        std::memcpy(&reference, range.bytes.data() + at, 8);
        select(reference);
      }
    }
  }

  engine::ExecuteOptions options;
  options.properties = properties;
  engine::MemoryImage image;
  engine::ObjectDirectory attempt;
  try {
    for (bool last = false;;) {
      image = engine::MemoryImage();
      result.bytesCopiedIn = 0;
      for (size_t g = 0; g < groups.size(); ++g) {
        if (!selected[g]) continue;
        const AliasGroup& group = groups[g];
        engine::MemoryRegion& region =
            image.add_region(group.base, group.end - group.base, group.usage, "buffer " + hex(group.buffers[0]->buffer));
        for (const ServedBuffer* b : group.buffers) {
          std::memcpy(region.bytes.data() + (b->address - group.base), b->host, b->size);
          result.bytesCopiedIn += b->size;
        }
      }
      // Over every buffer no further attempt can follow: the device's directory itself.
      last = last || std::find(selected.begin(), selected.end(), false) == selected.end();
      if (!last) attempt = directory;
      options.directory = last ? &directory : &attempt;
      result.record = engine::execute(command, image, options);
      ++result.attempts;
      if (last) break;
      if (result.record.findings.empty()) {
        directory = std::move(attempt);
        break;
      }
      bool grew = false;
      for (const engine::Finding& f : result.record.findings) grew |= select(f.address);
      if (!grew) selected.assign(groups.size(), true);
    }
  } catch (const std::exception& e) {
    result.error = e.what();
    return result;
  }
  result.ran = true;

  // Back into every buffer that holds a written byte (aliases included: same memory or not,
  // each view must show what the command wrote).
  for (const engine::MemoryAccess& access : result.record.accesses) {
    if (!access.is_write || access.end <= access.begin) continue;
    for (size_t g = groupOf(groups, access.begin); g < groups.size() && groups[g].base < access.end; ++g) {
      if (!selected[g]) continue;
      for (const ServedBuffer* b : groups[g].buffers) {
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
  }
  result.image = std::make_shared<const engine::MemoryImage>(std::move(image));
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
