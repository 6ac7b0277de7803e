#include "clastrace/capture/cluster_input_walker.h"

#include <cstring>

namespace clastrace::capture {
namespace {

using Info = VkClusterAccelerationStructureCommandsInfoNV;

uint32_t indexFormatBytes(uint32_t indexType) {
  switch (indexType) {
    case VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_8BIT_NV: return 1;
    case VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_16BIT_NV: return 2;
    case VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_32BIT_NV: return 4;
    default: return 0;
  }
}

// Bytes spanned by `count` elements of `elementBytes` placed `stride` apart (0: packed).
uint64_t stridedSpan(uint64_t count, uint64_t stride, uint64_t elementBytes) {
  if (count == 0) return 0;
  if (stride == 0) stride = elementBytes;
  return (count - 1) * stride + elementBytes;
}

class Walker {
 public:
  Walker(const DeviceMemoryReader& read, ClusterMemoryWalk& out) : read_(read), out_(out) {}

  bool capture(MemoryRole role, uint32_t entry, VkDeviceAddress address, uint64_t size) {
    if (size == 0) return true;
    CapturedRange range{role, entry, address, {}};
    std::string why;
    // Where the range is comes first (a garbage address is reported as such), its size second.
    if (!read_(address, size, nullptr, why)) {
      issue(address, size, std::string(memoryRoleName(role)) + ": " + why);
      return false;
    }
    if (total_ + size > kMaxCapturedBytesPerCommand || total_ + size < total_) {
      issue(address, size, "the ranges this command references exceed the capture's per-command limit of 1 GiB");
      return false;
    }
    if (!read_(address, size, &range.bytes, why)) {
      issue(address, size, std::string(memoryRoleName(role)) + ": " + why);
      return false;
    }
    total_ += size;
    out_.ranges.push_back(std::move(range));
    return true;
  }

  // Strided elements: packed strides are one range; sparse ones are one range per element, so
  // only bytes the command reads are captured.
  void captureStrided(MemoryRole role, uint32_t entry, VkDeviceAddress address, uint64_t count, uint64_t stride,
                      uint64_t elementBytes) {
    if (address == 0 || count == 0) return;
    if (stride == 0 || stride == elementBytes) {
      capture(role, entry, address, count * elementBytes);
      return;
    }
    if (stride < elementBytes) {  // overlapping elements: the union is contiguous
      capture(role, entry, address, stridedSpan(count, stride, elementBytes));
      return;
    }
    for (uint64_t i = 0; i < count; ++i)
      if (!capture(role, entry, address + i * stride, elementBytes)) return;
  }

  // captureStrided for arrays of little-endian 4- or 8-byte values, returning the values.
  std::vector<uint64_t> captureStridedValues(MemoryRole role, VkDeviceAddress address, uint64_t count,
                                             uint64_t stride, uint32_t elementBytes) {
    std::vector<uint64_t> values;
    const size_t before = out_.ranges.size();
    captureStrided(role, 0, address, count, stride, elementBytes);
    if (stride == 0) stride = elementBytes;
    auto value = [&](const uint8_t* bytes) {
      uint64_t v = 0;
      std::memcpy(&v, bytes, elementBytes);
      return v;
    };
    if (stride > elementBytes) {  // one range per element
      for (size_t r = before; r < out_.ranges.size(); ++r) values.push_back(value(out_.ranges[r].bytes.data()));
    } else if (out_.ranges.size() == before + 1) {  // one span
      const auto& bytes = out_.ranges[before].bytes;
      for (uint64_t i = 0; i < count; ++i) values.push_back(value(bytes.data() + i * stride));
    }
    return values;
  }

  ClusterMemoryWalk& result() { return out_; }

  const CapturedBytes* lastBytes() const { return out_.ranges.empty() ? nullptr : &out_.ranges.back().bytes; }

  void issue(VkDeviceAddress address, uint64_t size, std::string rule) {
    out_.issues.push_back({address, size, std::move(rule)});
  }

 private:
  const DeviceMemoryReader& read_;
  ClusterMemoryWalk& out_;
  uint64_t total_ = 0;
};

uint32_t srcInfoBytes(VkClusterAccelerationStructureOpTypeNV op) {
  switch (op) {
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV:
      return sizeof(VkClusterAccelerationStructureMoveObjectsInfoNV);
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV:
      return sizeof(VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV);
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV:
      return sizeof(VkClusterAccelerationStructureBuildTriangleClusterInfoNV);
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV:
      return sizeof(VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV);
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_INSTANTIATE_TRIANGLE_CLUSTER_NV:
      return sizeof(VkClusterAccelerationStructureInstantiateClusterInfoNV);
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_GET_CLUSTER_TEMPLATE_INDICES_NV:
      return sizeof(VkClusterAccelerationStructureGetTemplateIndicesInfoNV);
    default:
      return 0;
  }
}

// The triangle cluster info and its template variant share their first 64 bytes (the ABI
// header checks the offsets), so one reader serves both.
void followTriangleCluster(Walker& walker, uint32_t entry, const uint8_t* bytes, bool isTemplate,
                           const ClusterCommandParameters& p) {
  VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV info{};
  std::memcpy(&info, bytes, isTemplate ? sizeof(info) : sizeof(VkClusterAccelerationStructureBuildTriangleClusterInfoNV));
  const uint32_t triangles = info.triangleCount;
  const uint32_t vertices = info.vertexCount;

  const uint32_t indexBytes = indexFormatBytes(info.indexType);
  if (indexBytes == 0)
    walker.issue(info.indexBuffer, 0,
                 std::string(isTemplate ? "VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-indexType-10500"
                                        : "VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-indexType-10491") +
                     ": indexType " +
                     std::to_string(info.indexType) + " of srcInfosArray entry " + std::to_string(entry) +
                     " is not a single index format bit");
  else
    walker.captureStrided(MemoryRole::IndexBuffer, entry, info.indexBuffer, uint64_t(triangles) * 3,
                          info.indexBufferStride, indexBytes);

  const uint32_t vertexBytes = clusterVertexFormatBytes(p.triangleClusterInput.vertexFormat);
  if (info.vertexBuffer != 0) {
    if (vertexBytes == 0)
      walker.issue(info.vertexBuffer, 0,
                   "vertexFormat " + std::to_string(int(p.triangleClusterInput.vertexFormat)) +
                       " is not a format the layer knows the size of; vertices not captured");
    else
      walker.captureStrided(MemoryRole::VertexBuffer, entry, info.vertexBuffer, vertices, info.vertexBufferStride,
                            vertexBytes);
  }
  walker.captureStrided(MemoryRole::GeometryIndexAndFlags, entry, info.geometryIndexAndFlagsBuffer, triangles,
                        info.geometryIndexAndFlagsBufferStride,
                        sizeof(VkClusterAccelerationStructureGeometryIndexAndGeometryFlagsNV));
  if (info.opacityMicromapIndexBuffer != 0) {
    const uint32_t ommIndexBytes = indexFormatBytes(info.opacityMicromapIndexType);
    if (ommIndexBytes == 0)
      walker.issue(info.opacityMicromapIndexBuffer, 0,
                   std::string(isTemplate
                                   ? "VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-opacityMicromapIndexType-10501"
                                   : "VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-opacityMicromapIndexType-10492") +
                       ": opacityMicromapIndexType of srcInfosArray entry " + std::to_string(entry) +
                       " is not a single index format bit");
    else
      walker.captureStrided(MemoryRole::OpacityMicromapIndices, entry, info.opacityMicromapIndexBuffer, triangles,
                            info.opacityMicromapIndexBufferStride, ommIndexBytes);
  }
  if (isTemplate) walker.result().templateVertexCounts.push_back(vertices);
  if (isTemplate && info.instantiationBoundingBoxLimit != 0)
    walker.capture(MemoryRole::InstantiationBoundingBox, entry, info.instantiationBoundingBoxLimit, 6 * sizeof(float));
}

void followEntry(Walker& walker, uint32_t entry, const uint8_t* bytes, const ClusterCommandParameters& p,
                 const TemplateVertexCountLookup& templateVertexCount) {
  switch (p.info.input.opType) {
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV:
      followTriangleCluster(walker, entry, bytes, false, p);
      break;
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV:
      followTriangleCluster(walker, entry, bytes, true, p);
      break;
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV: {
      VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV info;
      std::memcpy(&info, bytes, sizeof info);
      walker.captureStrided(MemoryRole::ClusterReferences, entry, info.clusterReferences, info.clusterReferencesCount,
                            info.clusterReferencesStride, sizeof(VkDeviceAddress));
      break;
    }
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_INSTANTIATE_TRIANGLE_CLUSTER_NV: {
      // The vertex array holds as many vertices as the template has, which only its build said.
      VkClusterAccelerationStructureInstantiateClusterInfoNV info;
      std::memcpy(&info, bytes, sizeof info);
      if (info.vertexBuffer.startAddress == 0) break;
      const uint32_t vertexBytes = clusterVertexFormatBytes(p.triangleClusterInput.vertexFormat);
      uint32_t vertices = 0;
      if (vertexBytes == 0 || !templateVertexCount || !templateVertexCount(info.clusterTemplateAddress, &vertices)) {
        walker.issue(info.vertexBuffer.startAddress, 0,
                     "vertexBuffer of srcInfosArray entry " + std::to_string(entry) + " not captured: template " +
                         std::to_string(info.clusterTemplateAddress) + " was not built under the layer");
        break;
      }
      walker.captureStrided(MemoryRole::VertexBuffer, entry, info.vertexBuffer.startAddress, vertices,
                            info.vertexBuffer.strideInBytes, vertexBytes);
      break;
    }
    // Move sources and templates are objects earlier builds wrote (captured as their outputs).
    default:
      break;
  }
}

// With an INDIRECTED_* flag the field holds the address of the value rather than the value.
// The layer reads the value there (and keeps those bytes) before following it.
bool resolveIndirectAddress(Walker& walker, VkDeviceAddress& address) {
  if (address == 0) return true;
  if (!walker.capture(MemoryRole::IndirectAddress, 0, address, sizeof(VkDeviceAddress))) return false;
  std::memcpy(&address, walker.lastBytes()->data(), sizeof address);
  return true;
}

// A strided region's cell holds its deviceAddress only; stride and size stay the command's
// (docs/spec-readings.md). Cells of fields the walk does not follow are captured too: replay
// reads them again.
void captureIndirectCells(Walker& walker, const Info& info) {
  const auto flags = info.addressResolutionFlags;
  const auto mode = info.input.opMode;
  VkDeviceAddress scratch = info.scratchData, implicitData = info.dstImplicitData,
                  sizes = info.dstSizesArray.deviceAddress;
  if (flags & VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SCRATCH_DATA_BIT_NV)
    resolveIndirectAddress(walker, scratch);
  if (mode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV &&
      (flags & VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_IMPLICIT_DATA_BIT_NV))
    resolveIndirectAddress(walker, implicitData);
  if (flags & VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_SIZES_ARRAY_BIT_NV)
    resolveIndirectAddress(walker, sizes);
}

// dstAddressesArray's address after its indirection, if any (the cell is captured).
bool resolveDstAddresses(Walker& walker, const Info& info, VkDeviceAddress& address) {
  address = info.dstAddressesArray.deviceAddress;
  if (!(info.addressResolutionFlags & VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_ADDRESS_ARRAY_BIT_NV))
    return true;
  return resolveIndirectAddress(walker, address);
}

// The outputs walk reads a cell again to find its array; the cell is an input, kept by the
// inputs walk, so it is not kept here.
bool followIndirectCell(Walker& walker, VkDeviceAddress& address) {
  const size_t before = walker.result().ranges.size();
  const bool ok = resolveIndirectAddress(walker, address);
  walker.result().ranges.resize(before);
  return ok;
}

}  // namespace

uint32_t clusterVertexFormatBytes(VkFormat format) {
  switch (format) {
    case VK_FORMAT_R32G32B32_SFLOAT: return 12;
    case VK_FORMAT_R32G32B32A32_SFLOAT: return 16;
    case VK_FORMAT_R16G16B16A16_SFLOAT: return 8;
    case VK_FORMAT_R16G16B16_SFLOAT: return 6;
    case VK_FORMAT_R16G16B16A16_SNORM: return 8;
    case VK_FORMAT_R16G16_SFLOAT: return 4;
    default: return 0;
  }
}

ClusterMemoryWalk walkClusterInputs(const ClusterCommandParameters& p, const DeviceMemoryReader& read,
                                    const TemplateVertexCountLookup& templateVertexCount) {
  ClusterMemoryWalk out;
  Walker walker(read, out);
  const Info& info = p.info;
  const uint32_t maxCount = info.input.maxAccelerationStructureCount;
  const VkClusterAccelerationStructureAddressResolutionFlagsNV flags = info.addressResolutionFlags;

  VkDeviceAddress countAddress = info.srcInfosCount;
  if (flags & VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SRC_INFOS_COUNT_BIT_NV)
    if (!resolveIndirectAddress(walker, countAddress)) return out;
  uint32_t count = maxCount;
  if (countAddress != 0) {
    if (!walker.capture(MemoryRole::SrcInfosCount, 0, countAddress, sizeof(uint32_t))) return out;
    uint32_t value;
    std::memcpy(&value, walker.lastBytes()->data(), sizeof value);
    if (value > maxCount)
      walker.issue(countAddress, 4,
                   "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10453: srcInfosCount value " +
                       std::to_string(value) + " exceeds maxAccelerationStructureCount " + std::to_string(maxCount));
    count = value < maxCount ? value : maxCount;
  }
  const uint32_t entryBytes = srcInfoBytes(info.input.opType);
  if (entryBytes == 0) {
    walker.issue(0, 0, "opType " + std::to_string(int(info.input.opType)) + " is not an operation of spec version 4");
    return out;
  }
  VkStridedDeviceAddressRegionKHR src = info.srcInfosArray;
  if (flags & VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SRC_INFOS_ARRAY_BIT_NV)
    if (!resolveIndirectAddress(walker, src.deviceAddress)) return out;
  captureIndirectCells(walker, info);
  const uint64_t stride = src.stride ? src.stride : entryBytes;
  if (src.size != 0) {
    const uint64_t available = src.size < entryBytes ? 0 : (src.size - entryBytes) / stride + 1;
    if (available < count) {
      walker.issue(src.deviceAddress, src.size,
                   "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10454: srcInfosArray holds " +
                       std::to_string(available) + " entries, fewer than the " + std::to_string(count) + " executed");
      count = uint32_t(available);
    }
  }
  out.executedCount = count;
  if (count == 0) return out;
  if (src.deviceAddress == 0) {
    walker.issue(0, 0, "srcInfosArray.deviceAddress is 0 but the command executes " + std::to_string(count) + " entries");
    return out;
  }

  // The entries first (so a reader sees them before the data they point at), then per entry the
  // memory it references.
  const size_t firstEntryRange = out.ranges.size();
  walker.captureStrided(MemoryRole::SrcInfos, 0, src.deviceAddress, count, stride, entryBytes);
  const size_t lastEntryRange = out.ranges.size();
  if (lastEntryRange == firstEntryRange) return out;
  std::vector<uint8_t> entries;  // packed copy, one entry after another
  entries.reserve(uint64_t(count) * entryBytes);
  for (size_t r = firstEntryRange; r < lastEntryRange; ++r) {
    const CapturedBytes& bytes = out.ranges[r].bytes;
    if (stride == entryBytes || stride > entryBytes) {
      entries.insert(entries.end(), bytes.begin(), bytes.end());
    } else {  // overlapping entries were captured as one span: unpack them
      for (uint32_t i = 0; i < count; ++i)
        entries.insert(entries.end(), bytes.begin() + i * stride, bytes.begin() + i * stride + entryBytes);
    }
  }
  if (entries.size() < uint64_t(count) * entryBytes) return out;  // cut short; the issue says why
  for (uint32_t i = 0; i < count; ++i) followEntry(walker, i, entries.data() + uint64_t(i) * entryBytes, p, templateVertexCount);

  // Explicit destinations are read by the command, not written.
  VkDeviceAddress dstAddresses = 0;
  if (info.input.opMode != VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_COMPUTE_SIZES_NV &&
      !resolveDstAddresses(walker, info, dstAddresses))
    return out;
  if (info.input.opMode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV) {
    walker.captureStrided(MemoryRole::DstAddresses, 0, dstAddresses, count, info.dstAddressesArray.stride,
                          sizeof(VkDeviceAddress));
  }
  return out;
}

ClusterMemoryWalk walkClusterOutputs(const ClusterCommandParameters& p, uint32_t executedCount,
                                     const DeviceMemoryReader& read) {
  ClusterMemoryWalk out;
  out.executedCount = executedCount;
  Walker walker(read, out);
  const Info& info = p.info;
  if (executedCount == 0) return out;
  const bool computeSizes = info.input.opMode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_COMPUTE_SIZES_NV;
  const bool implicit = info.input.opMode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;

  VkDeviceAddress dstAddresses = info.dstAddressesArray.deviceAddress, dstSizes = info.dstSizesArray.deviceAddress;
  const auto flags = info.addressResolutionFlags;
  if ((flags & VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_ADDRESS_ARRAY_BIT_NV) &&
      !followIndirectCell(walker, dstAddresses))
    dstAddresses = 0;
  if ((flags & VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_SIZES_ARRAY_BIT_NV) &&
      !followIndirectCell(walker, dstSizes))
    dstSizes = 0;
  std::vector<uint64_t> addresses, sizes;
  if (!computeSizes && dstAddresses != 0) {
    const size_t before = out.ranges.size();
    addresses = walker.captureStridedValues(MemoryRole::DstAddresses, dstAddresses, executedCount,
                                            info.dstAddressesArray.stride, sizeof(VkDeviceAddress));
    if (!implicit) out.ranges.resize(before);  // explicit addresses were inputs, captured before
  }
  if (dstSizes != 0)
    sizes = walker.captureStridedValues(MemoryRole::DstSizes, dstSizes, executedCount, info.dstSizesArray.stride,
                                        sizeof(uint32_t));
  // The objects themselves, where both their address and size are known.
  if (!computeSizes && addresses.size() == executedCount && sizes.size() == executedCount) {
    out.ranges.reserve(out.ranges.size() + executedCount);  // (as many values were read already)
    for (uint32_t i = 0; i < executedCount; ++i)
      if (addresses[i] != 0 && sizes[i] != 0) walker.capture(MemoryRole::DstObject, i, addresses[i], sizes[i]);
  }
  return out;
}

}  // namespace clastrace::capture
