// SPDX-License-Identifier: Apache-2.0
// Cluster-level ops of VK_NV_cluster_acceleration_structure, on the CPU.
//
// Each op reads its inputs through a MemoryImage and returns the object's bytes exactly
// as a driver would write them to device memory (position independent; see
// cluster_format.h and docs/engine-formats.md), with the findings for every rule the
// input broke. An op whose input makes the object impossible to build (a memory fault,
// counts beyond the format, a missing template) returns ok == false and no bytes; rule
// breaks the engine can still build through (e.g. an index >= vertexCount, which becomes
// an inactive triangle) are findings on an ok object.
//
// Semantics the spec leaves implicit, as the engine applies them:
// - a triangle's geometry index is baseGeometryIndexAndGeometryFlags.geometryIndex plus
//   its geometryIndexAndFlagsBuffer entry's index (VUID ...-baseGeometryIndex-10496 speaks
//   of "the values in baseGeometryIndex and geometryIndexBuffer"); its flags are the OR of
//   both; without the buffer the base applies to every triangle;
// - index values >= vertexCount make their triangle inactive (finding
//   CLASTRACE-index-out-of-range); NaN coordinates (after truncation) make it inactive;
// - vertexBufferStride must be a multiple of the vertex format's component size (the
//   rule VUID ...-vertexBufferStride-10495 states against "vertexFormat", read as the
//   acceleration-structure rule for vertexStride);
// - opacityMicromapIndexType is checked only when an opacity micromap array or index
//   buffer is given (applications leave it 0 otherwise);
// - without opacityMicromapIndexBuffer, triangle i uses micromap index i (spec).
// - instantiation: clusterID = template clusterID + clusterIdOffset (mod 2^32);
//   geometryIndexOffset is a signed 24-bit offset; positions are truncated with the
//   template's positionTruncateBitCount.
#pragma once

#include "clastrace/engine/finding.h"
#include "clastrace/engine/memory_image.h"
#include "clastrace/engine/properties.h"
#include "clastrace/vk_cluster_abi.h"

#include <cstddef>
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

namespace clastrace::engine {

struct ClusterObject {
    std::vector<std::byte> bytes;  // the object; bytes.size() is the size a driver reports
    std::vector<Finding> findings;
    bool ok = false;
};

// How a builder writes each object into its `out` vector.
// - kCached: in place, through the caches, for callers that read the object back at once (as
//   execute() does when it copies it into the memory image).
// - kStreaming: laid out in the builder's scratch, then written once, in order, with
//   non-temporal stores (x86): the object's cache lines are not read for ownership first and
//   evict nothing, for bulk builds whose objects are read later. A vector that already holds
//   an object of the same size (a rebuild) is written without zero-filling it first.
enum class ObjectStores { kCached, kStreaming };

// Reusable build state: keeps its scratch between ops, so building many clusters does no
// heap allocation per cluster once warmed up. Not thread safe; use one per thread.
class ClusterBuilder {
public:
    explicit ClusterBuilder(
        const EngineProperties& properties = EngineProperties::nvidia_default());
    ~ClusterBuilder();
    ClusterBuilder(ClusterBuilder&&) noexcept;
    ClusterBuilder& operator=(ClusterBuilder&&) noexcept;

    // Each op writes the object into `out` (resized; its capacity is reused) and appends
    // findings to `findings`. Returns true when an object was built.
    bool build_triangle_cluster(
        const MemoryImage& memory,
        const VkClusterAccelerationStructureBuildTriangleClusterInfoNV& info,
        const VkClusterAccelerationStructureTriangleClusterInputNV& input, int64_t op_index,
        std::vector<std::byte>& out, std::vector<Finding>& findings);
    bool build_triangle_cluster_template(
        const MemoryImage& memory,
        const VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV& info,
        const VkClusterAccelerationStructureTriangleClusterInputNV& input, int64_t op_index,
        std::vector<std::byte>& out, std::vector<Finding>& findings);
    bool instantiate_triangle_cluster(
        const MemoryImage& memory,
        const VkClusterAccelerationStructureInstantiateClusterInfoNV& info,
        const VkClusterAccelerationStructureTriangleClusterInputNV& input, int64_t op_index,
        std::vector<std::byte>& out, std::vector<Finding>& findings);

    // Builds a CLAS straight from host arrays (tests, benchmarks): positions are xyz floats
    // (truncation applied here), indices 3 per triangle, geometry_index_and_flags one per
    // triangle or empty (then `base_geometry_index_and_flags` applies to all).
    bool build_from_arrays(uint32_t cluster_id, std::span<const float> positions,
                           std::span<const uint32_t> indices, uint32_t truncate_bits,
                           uint32_t base_geometry_index_and_flags,
                           std::span<const uint32_t> geometry_index_and_flags,
                           std::vector<std::byte>& out, std::vector<Finding>& findings);

    const EngineProperties& properties() const { return properties_; }
    void set_object_stores(ObjectStores stores) { stores_ = stores; }

private:
    struct Scratch;
    EngineProperties properties_;
    std::unique_ptr<Scratch> scratch_;
    ObjectStores stores_ = ObjectStores::kCached;
};

// One-shot forms of the ops (allocate a builder per call; use ClusterBuilder in loops).
ClusterObject build_triangle_cluster(
    const MemoryImage& memory, const VkClusterAccelerationStructureBuildTriangleClusterInfoNV& info,
    const VkClusterAccelerationStructureTriangleClusterInputNV& input,
    const EngineProperties& properties, int64_t op_index);
ClusterObject build_triangle_cluster_template(
    const MemoryImage& memory,
    const VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV& info,
    const VkClusterAccelerationStructureTriangleClusterInputNV& input,
    const EngineProperties& properties, int64_t op_index);
ClusterObject instantiate_triangle_cluster(
    const MemoryImage& memory, const VkClusterAccelerationStructureInstantiateClusterInfoNV& info,
    const VkClusterAccelerationStructureTriangleClusterInputNV& input,
    const EngineProperties& properties, int64_t op_index);

// VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_GET_CLUSTER_TEMPLATE_INDICES_NV: "the vertex
// indices of the cluster template ... will be fetched". The result, which the command
// writes to the op's destination (dstImplicitData / dstAddressesArray[i], size to
// dstSizesArray[i] like any other op), is the template's index buffer as the
// application gave it, widened to uint32: triangleCount*3 values in the original
// triangle order. Its size is therefore 12 * triangleCount bytes (COMPUTE_SIZES reports
// that; the implicit-destination upper bound is 12 * maxClusterTriangleCount).
// Fails (ok == false, finding kRuleNotATemplate) when the address holds no template.
ClusterObject get_cluster_template_indices(
    const MemoryImage& memory, const VkClusterAccelerationStructureGetTemplateIndicesInfoNV& info,
    int64_t op_index);

// Alignment of an object's address in device memory: clusterByteAlignment for a CLAS,
// clusterTemplateByteAlignment for a template (implicit destinations pack objects so).
inline uint32_t object_alignment(bool is_template, const EngineProperties& properties) {
    return is_template ? properties.cluster_template_byte_alignment
                       : properties.cluster_byte_alignment;
}

// Upper bound of one object's size for the given input maxima (what
// vkGetClusterAccelerationStructureBuildSizesNV sizes implicit destinations with). It
// holds for inputs within those maxima: an info that breaks ...-positionTruncateBitCount-10493
// (fewer bits truncated than minPositionTruncateBitCount) or exceeds the maxima (finding
// CLASTRACE-count-above-triangle-cluster-input) can produce a larger object.
uint64_t max_cluster_object_size(const VkClusterAccelerationStructureTriangleClusterInputNV& input,
                                 const EngineProperties& properties, bool is_template);

}  // namespace clastrace::engine
