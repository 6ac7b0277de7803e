#include "clastrace/capture/acceleration_structure_walker.h"

#include <cstring>

namespace clastrace::capture {
namespace {

uint32_t vertexBytes(VkFormat format) {
  switch (format) {
    case VK_FORMAT_R32G32B32_SFLOAT: return 12;
    case VK_FORMAT_R32G32_SFLOAT: return 8;
    case VK_FORMAT_R16G16B16A16_SFLOAT:
    case VK_FORMAT_R16G16B16A16_SNORM: return 8;
    case VK_FORMAT_R16G16_SFLOAT:
    case VK_FORMAT_R16G16_SNORM: return 4;
    default: return 0;
  }
}

uint32_t indexBytes(VkIndexType type) {
  switch (type) {
    case VK_INDEX_TYPE_UINT16: return 2;
    case VK_INDEX_TYPE_UINT32: return 4;
    case VK_INDEX_TYPE_UINT8_EXT: return 1;
    default: return 0;  // VK_INDEX_TYPE_NONE_NV: no index buffer
  }
}

struct BufferWalker {
  const BufferMemoryReader& read;
  ClusterMemoryWalk& out;
  uint64_t total = 0;

  void capture(MemoryRole role, uint32_t entry, uint64_t buffer, VkDeviceSize offset, uint64_t size) {
    if (buffer == 0 || size == 0) return;
    CapturedRange range{role, entry, 0, {}, buffer, offset};
    std::string why;
    if (!read(buffer, offset, size, nullptr, why)) {
      out.issues.push_back({0, size, std::string(memoryRoleName(role)) + " of geometry " + std::to_string(entry) + ": " + why});
      return;
    }
    if (total + size > kMaxCapturedBytesPerCommand) {
      out.issues.push_back({0, size, "the ranges this command references exceed the capture's per-command limit of 1 GiB"});
      return;
    }
    if (!read(buffer, offset, size, &range.bytes, why)) return;
    total += size;
    out.ranges.push_back(std::move(range));
  }
  // Element i at offset + i * stride, `element` bytes each: the span from the first to the last.
  void captureStrided(MemoryRole role, uint32_t entry, uint64_t buffer, VkDeviceSize offset, uint64_t count,
                      uint64_t stride, uint64_t element) {
    if (count == 0) return;
    if (stride == 0) stride = element;
    if (count > (UINT64_MAX - element) / stride) {
      out.issues.push_back({0, 0, std::string(memoryRoleName(role)) + ": element count overflows"});
      return;
    }
    capture(role, entry, buffer, offset, (count - 1) * stride + element);
  }
};

}  // namespace

ClusterMemoryWalk walkBuildAccelerationStructureNVInputs(const BuildAccelerationStructureNVCommand& c,
                                                         const BufferMemoryReader& read) {
  ClusterMemoryWalk out;
  BufferWalker walker{read, out};
  for (uint32_t g = 0; g < c.geometries.size(); ++g) {
    const VkGeometryNV& geometry = c.geometries[g];
    if (geometry.geometryType == VK_GEOMETRY_TYPE_TRIANGLES_NV) {
      const VkGeometryTrianglesNV& t = geometry.geometry.triangles;
      const uint32_t vb = vertexBytes(t.vertexFormat);
      if (vb == 0)
        out.issues.push_back({0, 0, "vertexFormat " + std::to_string(int(t.vertexFormat)) + " of geometry " +
                                        std::to_string(g) + " has no known size; vertices not captured"});
      else
        walker.captureStrided(MemoryRole::VertexBuffer, g, uint64_t(t.vertexData), t.vertexOffset, t.vertexCount,
                              t.vertexStride, vb);
      if (const uint32_t ib = indexBytes(t.indexType))
        walker.capture(MemoryRole::IndexBuffer, g, uint64_t(t.indexData), t.indexOffset, uint64_t(t.indexCount) * ib);
      walker.capture(MemoryRole::TransformData, g, uint64_t(t.transformData), t.transformOffset, 12 * sizeof(float));
    } else if (geometry.geometryType == VK_GEOMETRY_TYPE_AABBS_NV) {
      const VkGeometryAABBNV& a = geometry.geometry.aabbs;
      walker.captureStrided(MemoryRole::Aabbs, g, uint64_t(a.aabbData), a.offset, a.numAABBs, a.stride,
                            6 * sizeof(float));
    }
  }
  // VkAccelerationStructureInstanceNV is 64 bytes, packed.
  if (c.type == VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_NV)
    walker.capture(MemoryRole::Instances, 0, c.instanceData, c.instanceOffset, uint64_t(c.instanceCount) * 64);
  out.executedCount = uint32_t(c.geometries.size());
  return out;
}

ClusterMemoryWalk walkCopyMemoryToAccelerationStructureInputs(const CopyMemoryToAccelerationStructureCommand& c,
                                                              const DeviceMemoryReader& read) {
  ClusterMemoryWalk out;
  constexpr uint64_t kSizeOffset = 2 * VK_UUID_SIZE;
  CapturedBytes header;
  std::string why;
  if (!read(c.src, kSizeOffset + 8, &header, why)) {
    out.issues.push_back({c.src, kSizeOffset + 8, "serialized acceleration structure header: " + why});
    return out;
  }
  uint64_t total;
  std::memcpy(&total, header.data() + kSizeOffset, 8);
  if (total < kSizeOffset + 8 || total > kMaxCapturedBytesPerCommand) {
    out.issues.push_back({c.src, total, "serialized acceleration structure claims " + std::to_string(total) +
                                            " bytes; only its header was captured"});
    out.ranges.push_back({MemoryRole::SerializedAccelerationStructure, 0, c.src, std::move(header)});
    return out;
  }
  CapturedRange range{MemoryRole::SerializedAccelerationStructure, 0, c.src, {}};
  if (!read(c.src, total, &range.bytes, why)) {
    out.issues.push_back({c.src, total, "serialized acceleration structure: " + why});
    out.ranges.push_back({MemoryRole::SerializedAccelerationStructure, 0, c.src, std::move(header)});
    return out;
  }
  out.ranges.push_back(std::move(range));
  out.executedCount = 1;
  return out;
}

}  // namespace clastrace::capture
