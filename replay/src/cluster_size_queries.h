// SPDX-License-Identifier: Apache-2.0
// The vkGetClusterAccelerationStructureBuildSizesNV answers a trace holds, and the one that
// sizes a cluster command. A driver may touch every byte of the scratch and implicit region it
// answered for an input, not only the bytes the engine happens to use, so the command's
// scratch and implicit destination ranges (VUIDs 12300/12302/12303 and hazards) take these
// sizes. The answer matches a command when every field the answer depends on is equal: op
// type, op mode, maxAccelerationStructureCount, flags and the op input's limits.
#pragma once

#include <clastrace/engine/execute.h>
#include <clastrace/engine/properties.h>
#include <clastrace/traces/trace_generated.h>
#include <clastrace/vk_cluster_abi.h>

#include <cstdint>
#include <map>
#include <string>
#include <utility>
#include <vector>

namespace clastrace::replay::detail {

// The sizes one command's ranges take.
struct ClusterDriverSizes {
    uint64_t build_scratch_size = 0;
    uint64_t acceleration_structure_size = 0;  // implicit: the region; explicit: one object
    bool queried = false;  // false: no query in the trace matched; the engine's worst case
    // "answered by ..." / "assumed: ...", to follow a size in finding text.
    std::string source() const;
    engine::ExecuteOptions::AnsweredSizes answered() const;
};

class ClusterSizeQueries {
public:
    void on_query(const fbs::GetClusterBuildSizes& query);
    // The largest maxAccelerationStructureCount queried for the op type and mode (10445);
    // 0: none.
    uint32_t largest_count(uint32_t op_type, uint32_t op_mode) const;
    // The matching query's answer, else the engine's worst case for the input.
    ClusterDriverSizes sizes_for(const VkClusterAccelerationStructureInputInfoNV& input,
                                 const engine::EngineProperties& properties) const;

    // Distinct inputs kept (a hostile trace may query without end); later ones are not matched.
    static constexpr size_t kMaxInputs = 1 << 16;

private:
    struct Answer {
        uint64_t build_scratch_size = 0;
        uint64_t acceleration_structure_size = 0;
    };
    std::map<std::vector<uint64_t>, Answer> answers_;
    std::map<std::pair<uint32_t, uint32_t>, uint32_t> largest_count_;  // (type, mode) -> count
};

}  // namespace clastrace::replay::detail
