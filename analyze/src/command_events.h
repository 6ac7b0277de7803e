// SPDX-License-Identifier: Apache-2.0
// One replayed command turned into analyzer events (HeldCommand), and the trace state the
// records before it established (buffers, objects, build-sizes answers) that this needs.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <optional>
#include <unordered_map>
#include <vector>

#include <clastrace/engine/cluster_build.h>
#include <clastrace/replay/replay_observer.h>
#include <clastrace/traces/trace_generated.h>
#include <clastrace/vk_cluster_abi.h>

#include "clastrace/analyze/input.h"

namespace clastrace::analyze::detail {

struct HeldCommand {
    enum class Kind : uint8_t { kWork, kSync, kTimestamp, kLabel };
    Kind kind = Kind::kWork;
    CommandInfo info;
    std::optional<BuildSizesInfo> query;
    std::vector<RegionInfo> regions;
    std::vector<ObjectInfo> objects;
    std::vector<HazardSummary> hazards;
    std::vector<uint64_t> hazard_folds;  // per hazard: per-op hazards folded into it
    uint32_t command_buffer_index = 0;
    uint64_t ticks = 0;  // timestamps only
    bool ticks_valid = false;

    std::size_t held_bytes() const;
};

// Buffers, acceleration-structure objects and build-sizes answers, as the records so far
// declared them. Bounded by what the trace keeps alive (destroyed buffers are dropped) plus
// at most kMaxQueries distinct build-sizes inputs.
class RecordedState {
public:
    static constexpr std::size_t kMaxQueries = 4096;
    void on_record(const fbs::Record& record);

    struct Buffer {
        uint64_t handle = 0, base = 0, size = 0;
    };
    // The bound buffer holding `address`, if any.
    std::optional<Buffer> buffer_at(uint64_t address) const;
    std::optional<uint64_t> buffer_address(uint64_t handle) const;
    // The build-sizes answer for this input: same input, else the latest with the same op type and mode.
    std::optional<BuildSizesInfo> query_for(const fbs::ClusterInputInfo& input) const;
    uint64_t nv_object_bytes(uint64_t handle) const;
    uint64_t nv_build_scratch_bytes(uint64_t handle) const;
    struct KhrObject {
        uint64_t buffer = 0, offset = 0, size = 0;
        uint32_t type = 0;
    };
    const KhrObject* khr_object(uint64_t handle) const;
    uint64_t queries_dropped() const { return queries_dropped_; }

private:
    struct BufferInfo {
        uint64_t size = 0, address = 0;
    };
    std::unordered_map<uint64_t, BufferInfo> buffers_;
    std::map<uint64_t, Buffer> by_address_;  // base -> bound buffer
    std::unordered_map<uint64_t, uint64_t> nv_object_bytes_, nv_scratch_bytes_;
    std::unordered_map<uint64_t, KhrObject> khr_objects_;
    std::map<std::vector<uint64_t>, BuildSizesInfo> queries_;
    std::map<std::pair<uint32_t, uint32_t>, BuildSizesInfo> latest_query_;
    uint64_t queries_dropped_ = 0;
};

struct TemplateShape {
    uint32_t triangles = 0, vertices = 0, truncate_bits = 0;
};

struct DescribeContext {
    const RecordedState& recorded;
    std::unordered_map<uint64_t, TemplateShape>& templates;  // by rebuilt template address
    engine::ClusterBuilder& builder;
    uint32_t rebuild_budget = 0;
    const std::function<bool(uint64_t hash, std::vector<uint8_t>* bytes)>& contents;
    uint64_t rebuilds = 0;  // out: untruncated rebuilds done
};

// Fills `out` (except hazards and GPU time) for one replayed command.
void describe_command(const replay::ReplayedCommand& command, DescribeContext& context,
                      HeldCommand* out);

}  // namespace clastrace::analyze::detail
