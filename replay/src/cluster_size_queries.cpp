// SPDX-License-Identifier: Apache-2.0
#include "cluster_size_queries.h"

#include <clastrace/common/enum_bits.h>
#include <clastrace/engine/build_sizes.h>
#include <clastrace/traces/cluster_conversions.h>

#include <algorithm>

namespace clastrace::replay::detail {

namespace {

// Every field of the input the answer depends on, so a command and a query compare as inputs.
// Enum fields go by their bits: nothing has checked them yet (common/enum_bits.h).
std::vector<uint64_t> input_key(const VkClusterAccelerationStructureInputInfoNV& in) {
    using common::enum_bits;
    std::vector<uint64_t> k{enum_bits(in.opType), enum_bits(in.opMode),
                            in.maxAccelerationStructureCount, in.flags};
    switch (enum_bits(in.opType)) {
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV:
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV:
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_INSTANTIATE_TRIANGLE_CLUSTER_NV:
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_GET_CLUSTER_TEMPLATE_INDICES_NV:
        if (const auto* t = in.opInput.pTriangleClusters)
            k.insert(k.end(), {enum_bits(t->vertexFormat), t->maxGeometryIndexValue,
                               t->maxClusterUniqueGeometryCount, t->maxClusterTriangleCount,
                               t->maxClusterVertexCount, t->maxTotalTriangleCount,
                               t->maxTotalVertexCount, t->minPositionTruncateBitCount});
        break;
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV:
        if (const auto* b = in.opInput.pClustersBottomLevel)
            k.insert(k.end(),
                     {b->maxTotalClusterCount, b->maxClusterCountPerAccelerationStructure});
        break;
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV:
        if (const auto* m = in.opInput.pMoveObjects)
            k.insert(k.end(), {enum_bits(m->type), uint64_t(m->noMoveOverlap), m->maxMovedBytes});
        break;
    default: break;
    }
    return k;
}

}  // namespace

std::string ClusterDriverSizes::source() const {
    return queried ? "answered by the trace's vkGetClusterAccelerationStructureBuildSizesNV "
                     "query for this input"
                   : "assumed as the engine's worst case, since no "
                     "vkGetClusterAccelerationStructureBuildSizesNV query in the trace matches "
                     "this input";
}

engine::ExecuteOptions::AnsweredSizes ClusterDriverSizes::answered() const {
    return {build_scratch_size, acceleration_structure_size, source()};
}

void ClusterSizeQueries::on_query(const fbs::GetClusterBuildSizes& query) {
    if (!query.input()) return;
    uint32_t& m = largest_count_[{query.input()->op_type(), query.input()->op_mode()}];
    m = std::max(m, query.input()->max_acceleration_structure_count());
    traces::ClusterOpInputStorage storage;
    std::vector<uint64_t> key =
        input_key(traces::cluster_input_from_record(query.input(), storage));
    const Answer answer{query.build_scratch_size(), query.acceleration_structure_size()};
    auto it = answers_.find(key);
    if (it != answers_.end())
        it->second = answer;  // the latest answer for an input stands
    else if (answers_.size() < kMaxInputs)
        answers_.emplace(std::move(key), answer);
}

uint32_t ClusterSizeQueries::largest_count(uint32_t op_type, uint32_t op_mode) const {
    auto it = largest_count_.find({op_type, op_mode});
    return it == largest_count_.end() ? 0 : it->second;
}

ClusterDriverSizes ClusterSizeQueries::sizes_for(
    const VkClusterAccelerationStructureInputInfoNV& input,
    const engine::EngineProperties& properties) const {
    auto it = answers_.find(input_key(input));
    if (it != answers_.end())
        return {it->second.build_scratch_size, it->second.acceleration_structure_size, true};
    const engine::BuildSizes worst = engine::cluster_build_sizes(input, properties);
    return {worst.build_scratch_size, worst.acceleration_structure_size, false};
}

}  // namespace clastrace::replay::detail
