// SPDX-License-Identifier: Apache-2.0
// Cluster builds run ahead of their turn (docs/replay.md "Threads"). A capture records the bytes
// a cluster command reads as it saw them (its input snapshots), so the command can run early,
// on another thread, on an image of its own: the regions it names, holding only its snapshots.
// At its turn, after replay laid its snapshots in and translated its addresses as always, the
// run is taken only when every byte it read is the same in the replay's memory now, it wrote
// nothing it read, the buffers and size answers it was judged against are the same, and it
// found nothing; then its written bytes and built objects are copied over in one go. Anything
// else runs the command again, in place, as a one-thread replay does.
#pragma once

#include "cluster_size_queries.h"
#include "replay_memory.h"

#include <clastrace/engine/execution_record.h>
#include <clastrace/engine/memory_image.h>
#include <clastrace/engine/object_directory.h>
#include <clastrace/engine/properties.h>
#include <clastrace/replay/replayer.h>
#include <clastrace/traces/cluster_conversions.h>

#include <tbb/task_group.h>

#include <cstdint>
#include <deque>
#include <list>
#include <memory>
#include <mutex>
#include <optional>
#include <span>
#include <unordered_map>
#include <utility>
#include <vector>

namespace clastrace::replay::detail {

// The bytes of contents records the replay read recently, least recently used dropped first,
// so a command running ahead gets its snapshots without asking the reader (whose budget and
// damage list must see the calls of a one-thread replay, no more).
class RecentContents {
public:
    explicit RecentContents(uint64_t max_bytes) : max_bytes_(max_bytes) {}
    void keep(uint64_t hash, const uint8_t* data, size_t size);
    const std::vector<uint8_t>* find(uint64_t hash);  // nullptr when not kept

private:
    using Entry = std::pair<uint64_t, std::vector<uint8_t>>;
    std::list<Entry> order_;  // most recently used first
    std::unordered_map<uint64_t, std::list<Entry>::iterator> by_hash_;
    uint64_t bytes_ = 0, max_bytes_;
};

// What the replay knows when it starts a command ahead: its memory as of now (for the regions'
// bounds and snapshot addresses), the contents read so far and the size answers.
struct AheadInputs {
    const ReplayMemory& memory;
    RecentContents& contents;
    const ClusterSizeQueries& queries;
    const engine::EngineProperties& properties;  // outlives the run
    uint32_t max_findings_per_rule = 64;
};

class ClusterRunAhead {
public:
    // Starts the command of `record` (a CmdBuildClusterAccelerationStructureIndirect's Record
    // bytes) on a task of the calling thread's arena, or nullptr when it cannot run ahead: an
    // op type that reads objects through the directory (cluster BLASes, moves, instantiations,
    // template indices), a snapshot whose contents are not at hand or that no region holds.
    static std::unique_ptr<ClusterRunAhead> start(std::vector<uint8_t> record,
                                                  uint64_t stream_index, const AheadInputs& in);
    ~ClusterRunAhead() { group_.wait(); }

    const std::vector<uint8_t>& record() const { return record_; }
    bool stood() const { return stood_; }  // commit took it
    uint64_t stream_index() const { return stream_index_; }

    // At the command's turn, with its snapshots laid in and addresses translated: true when the
    // early run stands (the checks in the file comment); its bytes and objects then land in
    // `memory` and `directory`, and its record and engine time go to *record and *engine_ns.
    bool commit(ReplayMemory& memory, engine::ObjectDirectory& directory,
                uint32_t queried_max_count, const ClusterDriverSizes& sizes,
                engine::ExecutionRecord* record, uint64_t* engine_ns);

    // The checks commit makes without landing anything (a test breaks them through this).
    static bool skip_checks_for_tests;

private:
    ClusterRunAhead() = default;
    bool prepare_image(const fbs::CmdBuildClusterAccelerationStructureIndirect& build,
                       const AheadInputs& in);
    void run(const engine::EngineProperties& properties, uint32_t max_findings_per_rule,
             uint64_t implicit_object_room);
    bool stands(const ReplayMemory& memory, uint32_t queried_max_count,
                const ClusterDriverSizes& sizes) const;
    bool reads_unchanged(const engine::MemoryImage& real) const;
    bool writes_fit(const engine::MemoryImage& real) const;
    // The objects it built, when each is intact in its own image.
    struct Built {
        uint64_t address = 0, size = 0;
        engine::ObjectType type{};
    };
    bool built_objects(std::vector<Built>* objects) const;

    struct UsageQuery {
        uint64_t begin = 0, end = 0;
        uint32_t usage = 0;
    };
    std::vector<uint8_t> record_;
    uint64_t stream_index_ = 0;
    traces::ClusterOpInputStorage op_inputs_;
    VkClusterAccelerationStructureCommandsInfoNV info_{};
    uint32_t queried_max_count_ = 0;
    ClusterDriverSizes sizes_;
    engine::MemoryImage image_;
    engine::ObjectDirectory directory_;
    std::vector<std::pair<uint64_t, uint64_t>> writes_;  // (address, size), as written
    std::mutex usage_mutex_;
    std::vector<UsageQuery> usage_queries_;  // all answered "every byte has the usage"
    engine::ExecutionRecord result_;
    uint64_t engine_ns_ = 0;
    bool failed_ = false;
    bool stood_ = false;
    tbb::task_group group_;  // its own, so that its turn waits for it alone
};

// The commands started ahead and not yet taken, at most `capacity`.
class RunAheadWindow {
public:
    explicit RunAheadWindow(size_t capacity) : capacity_(capacity) {}
    bool full() const { return runs_.size() >= capacity_; }
    void add(std::unique_ptr<ClusterRunAhead> run) { runs_.push_back(std::move(run)); }
    bool holds(uint64_t stream_index) const;  // a run of the record at this index
    // A run of a record with these bytes (any: a run stands or not by the bytes it read);
    // nullptr when none.
    std::unique_ptr<ClusterRunAhead> take(std::span<const uint8_t> record);
    // Drops the runs of records read before stream index `index` (their command buffers were
    // not in the submission just replayed).
    void drop_before(uint64_t index);

    ReplayOptions::RunAheadCounts counts;

private:
    size_t capacity_;
    std::deque<std::unique_ptr<ClusterRunAhead>> runs_;
};

}  // namespace clastrace::replay::detail
