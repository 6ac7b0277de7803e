// SPDX-License-Identifier: Apache-2.0
// One vkCmdBuildClusterAccelerationStructureIndirectNV during replay: captured object
// addresses translated to rebuilt ones, engine::execute, accesses to the sync model,
// and the capture's outputs compared with the engine's.
#pragma once

#include "cluster_size_queries.h"
#include "cluster_speculation.h"
#include "replay_memory.h"
#include "sync_model_feed.h"

#include <clastrace/common/hex.h>

#include <clastrace/engine/execution_record.h>
#include <clastrace/engine/object_directory.h>
#include <clastrace/engine/properties.h>
#include <clastrace/replay/replay_report.h>
#include <clastrace/replay/replayer.h>
#include <clastrace/traces/trace_generated.h>

#include <functional>
#include <string>
#include <unordered_map>
#include <unordered_set>
#include <vector>

namespace clastrace::replay::detail {

using common::hex;

// Captured object address -> the address the engine rebuilt that object at. In a trace
// made by the engine itself every entry maps to itself.
struct AddressTranslation {
    std::unordered_map<uint64_t, uint64_t> rebuilt_at;
    std::unordered_set<uint64_t> rebuilt;  // every address the engine built an object at
    std::unordered_map<uint64_t, uint64_t>
        translated_cells;  // memory cell -> value replay wrote there
};

struct ClusterCommandContext {
    ReplayMemory& memory;
    engine::ObjectDirectory& directory;
    AddressTranslation& translation;
    const engine::EngineProperties& properties;
    const ReplayOptions& options;
    ReplayReport& report;
    SyncModelFeed& sync;
    const CommandRef& ref;
    const ReplayLocation& where;
    bool engine_trace;
    std::function<void(ReplayFinding)> add_finding;
    std::function<bool(uint64_t hash, std::vector<uint8_t>* bytes)> contents;
    // For a ReplayObserver: the engine's record and its time are moved here when non-null.
    engine::ExecutionRecord* executed = nullptr;
    uint64_t* engine_ns = nullptr;
    // The command's run ahead of its turn (cluster_speculation.h), taken when it stands.
    ClusterRunAhead* ahead = nullptr;
};

// queried_max_count: the largest count queried for the command's op type and mode (10445);
// queries: the answers that size its scratch and implicit ranges (cluster_size_queries.h).
void run_cluster_command(const fbs::CmdBuildClusterAccelerationStructureIndirect& build,
                         uint32_t queried_max_count, const ClusterSizeQueries& queries,
                         ClusterCommandContext& context);

}  // namespace clastrace::replay::detail
