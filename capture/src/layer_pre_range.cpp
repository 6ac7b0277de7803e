// SPDX-License-Identifier: Apache-2.0
// Pre-range state (layer_pre_range.h): per device, the last build or copy of each structure made
// before CLASTRACE_FRAME_RANGE starts, with the bytes it read at execution, written at the start
// of the range as one synthetic submission. Kept per command (one KHR build may build several
// structures): a command is dropped once every structure it produced was rebuilt or destroyed.
#include "layer_pre_range.h"

#include "layer_pre_range_clusters.h"
#include "layer_state.h"

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <map>
#include <mutex>
#include <optional>
#include <set>
#include <tuple>

namespace clastrace::capture {
namespace {

// Replay must see a structure's inputs built before what reads it: cluster-free levels, in this
// order, each in the order the application ran them (an update or copy after its source).
enum class StateLevel { kBottom = 0, kTop = 1 };

struct KeptCommand {
    uint64_t sequence = 0;  // execution order before the range
    StateLevel level = StateLevel::kBottom;
    RecordedCommand command;
    std::set<uint64_t> produced;  // structures this command built or copied into
    std::set<uint64_t> current;   // those of them still holding what it made
    std::set<uint64_t> memories;  // the memory its KHR structures' buffers were bound to
    std::optional<ClusterBuildCapture> capture;
};

using CaptureKey = std::tuple<uint64_t, uint64_t, uint32_t>;  // submission, pause, occurrence

struct PreRangeStore {
    std::mutex mutex;
    std::condition_variable arrived;
    std::map<CaptureKey, KeptCommand> kept;
    PreRangeClusterCommands clusters;  // run first in the prelude: a top level may name them
    std::set<uint64_t> submissions;    // before the range, their captures still to come
    uint64_t next_sequence = 0;
    bool written = false;
};

std::mutex storesMutex;
std::map<const DeviceState*, std::unique_ptr<PreRangeStore>> stores;

PreRangeStore& store_of(const DeviceState& d) {
    std::lock_guard lock(storesMutex);
    auto& s = stores[&d];
    if (!s) s = std::make_unique<PreRangeStore>();
    return *s;
}

bool is_top_level_khr(const KhrBuildInfo& info) {
    return info.info.type == VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR;
}

// The kept form of `pause`'s command: what it produces, at which level. False for a command
// that produces no structure (a copy to memory).
bool describe(const PausePoint& pause, KeptCommand& out) {
    if (pause.build_khr) {
        out.command = *pause.build_khr;
        for (const KhrBuildInfo& info : pause.build_khr->infos) {
            out.produced.insert(handle_id(info.info.dstAccelerationStructure));
            if (is_top_level_khr(info)) out.level = StateLevel::kTop;
        }
    } else if (pause.build_nv) {
        out.command = *pause.build_nv;
        out.produced.insert(pause.build_nv->dst);
        if (pause.build_nv->type == VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_NV)
            out.level = StateLevel::kTop;
    } else if (pause.copy_acceleration_structure && !pause.copy_acceleration_structure->to_memory) {
        out.command = *pause.copy_acceleration_structure;
        out.produced.insert(pause.copy_acceleration_structure->dst);
    } else {
        return false;
    }
    return !out.produced.empty();
}

// Structures `command` reads as its source (updates, copies): their producers stay while a
// kept reader needs them.
std::set<uint64_t> sources_of(const RecordedCommand& command) {
    std::set<uint64_t> sources;
    if (const auto* b = std::get_if<BuildAccelerationStructuresKHRCommand>(&command))
        for (const KhrBuildInfo& info : b->infos)
            if (info.info.mode == VK_BUILD_ACCELERATION_STRUCTURE_MODE_UPDATE_KHR)
                sources.insert(handle_id(info.info.srcAccelerationStructure));
    if (const auto* n = std::get_if<BuildAccelerationStructureNVCommand>(&command))
        if (n->update) sources.insert(n->src);
    if (const auto* c = std::get_if<CopyAccelerationStructureCommand>(&command))
        sources.insert(c->src);
    return sources;
}

// `structure` no longer holds what older commands made: a command goes once none of its
// structures holds its output and no later kept command reads one of them as its source.
void supersede(PreRangeStore& s, uint64_t structure) {
    for (auto& [key, k] : s.kept) k.current.erase(structure);
    for (auto it = s.kept.begin(); it != s.kept.end();) {
        const KeptCommand& k = it->second;
        const bool read_later = std::any_of(s.kept.begin(), s.kept.end(), [&](const auto& other) {
            if (other.second.sequence <= k.sequence) return false;
            const std::set<uint64_t> sources = sources_of(other.second.command);
            return std::any_of(k.produced.begin(), k.produced.end(),
                               [&](uint64_t p) { return sources.count(p) != 0; });
        });
        it = k.current.empty() && !read_later ? s.kept.erase(it) : std::next(it);
    }
}

uint64_t kept_bytes(const PreRangeStore& s) {
    uint64_t bytes = 0;
    for (const auto& [key, k] : s.kept)
        if (k.capture)
            for (const CapturedRange& r : k.capture->inputs) bytes += r.bytes.size();
    return bytes;
}

uint64_t& pause_id_in(RecordedCommand& command) {
    if (auto* b = std::get_if<BuildAccelerationStructuresKHRCommand>(&command)) return b->pause_id;
    if (auto* n = std::get_if<BuildAccelerationStructureNVCommand>(&command)) return n->pause_id;
    return std::get<CopyAccelerationStructureCommand>(command).pause_id;
}

// Between two prelude commands: everything before complete and visible to everything after.
BarrierCommand full_barrier() {
    BarrierCommand b;
    b.synchronization2 = true;
    MemoryBarrier m;
    m.src_stage = m.dst_stage = VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT;
    m.src_access = VK_ACCESS_2_MEMORY_WRITE_BIT;
    m.dst_access = VK_ACCESS_2_MEMORY_READ_BIT | VK_ACCESS_2_MEMORY_WRITE_BIT;
    b.memory_barriers.push_back(m);
    return b;
}

// The kept commands in the order replay must run them: bottom levels (and their copies) before
// top levels, each level in execution order.
std::vector<KeptCommand*> prelude_order(PreRangeStore& s) {
    std::vector<KeptCommand*> order;
    for (auto& [key, k] : s.kept) order.push_back(&k);
    std::sort(order.begin(), order.end(), [](const KeptCommand* a, const KeptCommand* b) {
        return std::tie(a->level, a->sequence) < std::tie(b->level, b->sequence);
    });
    return order;
}

// Waits (bounded) for the captures of the submissions before the range: they were submitted
// before the captured one, so the queue reaches their pauses unless it waits on the host.
void wait_for_captures(PreRangeStore& s, std::unique_lock<std::mutex>& lock) {
    const auto all_arrived = [&] {
        return s.clusters.all_arrived() &&
               std::all_of(s.kept.begin(), s.kept.end(),
                           [](const auto& entry) { return entry.second.capture.has_value(); });
    };
    if (s.arrived.wait_for(lock, std::chrono::seconds(10), all_arrived)) return;
    log_message(LogLevel::kError,
                "pre-range state: the captures of some builds before the frame range did not "
                "arrive within 10 s; they are written without their input bytes");
}

// The memory a KHR structure lives in (through its buffer); 0 when the layer does not know it.
uint64_t memory_of_structure(const DeviceState& d, uint64_t structure) {
    const KhrStructureStorage storage = khr_structure_storage(d, structure);
    if (!storage.buffer) return 0;
    const std::optional<TrackedBuffer> buffer = d.memory_map.buffer(storage.buffer);
    return buffer ? buffer->memory : 0;
}

// What the prelude holds, said at info level and in its PreRangeState record.
PreRangeStateRecord marker_of(const PreRangeStore& s, const SubmissionRecord& captured,
                              uint64_t index) {
    std::set<uint64_t> structures;
    for (const auto& [key, k] : s.kept) structures.insert(k.current.begin(), k.current.end());
    PreRangeStateRecord marker;
    marker.queue = captured.queue;
    marker.first_frame = layer_config().frame_range.first;
    marker.prelude_submission = index;
    marker.cluster_commands = uint32_t(s.clusters.size());
    marker.structures = uint32_t(structures.size()) + s.clusters.live_objects();
    marker.commands = uint32_t(s.kept.size()) + marker.cluster_commands;
    marker.bytes = kept_bytes(s) + s.clusters.bytes(false);
    log_message(LogLevel::kInfo,
                "pre-range state: %u structures from %u commands (%u cluster commands) before "
                "frame %llu, %llu input bytes kept (and %llu bytes of cluster outputs)",
                marker.structures, marker.commands, marker.cluster_commands,
                (unsigned long long)marker.first_frame, (unsigned long long)marker.bytes,
                (unsigned long long)s.clusters.bytes(true));
    return marker;
}

}  // namespace

bool before_frame_range(const DeviceState& d, uint64_t index) {
    const LayerConfig& config = layer_config();
    return config.pre_range_state && d.capturing_now() && config.frame_range.first > 0 &&
           current_frame() < config.frame_range.first && config.submit_range.contains(index);
}

bool produces_pre_range_state(const PausePoint& pause) {
    if (pause.parameters) return writes_cluster_objects(*pause.parameters);
    KeptCommand unused;
    return describe(pause, unused);
}

void note_pre_range_submission(DeviceState& d, uint64_t index,
                               const std::vector<const PausePoint*>& pauses) {
    PreRangeStore& s = store_of(d);
    std::lock_guard lock(s.mutex);
    if (s.written) return;
    s.submissions.insert(index);
    for (const PausePoint* pause : pauses) {
        if (pause->parameters) {  // a cluster command, both of whose pauses are read
            if (pause->phase == PausePhase::kBeforeCommand)
                s.clusters.note({index, pause->pause_id, pause->occurrence},
                                ClusterBuildCommand{*pause->parameters, pause->pause_id,
                                                    d.serving});
            continue;
        }
        KeptCommand k;
        if (!describe(*pause, k)) continue;
        for (uint64_t structure : k.produced) supersede(s, structure);
        k.sequence = s.next_sequence++;
        k.current = k.produced;
        for (uint64_t structure : k.produced)
            if (uint64_t memory = memory_of_structure(d, structure)) k.memories.insert(memory);
        s.kept[{index, pause->pause_id, pause->occurrence}] = std::move(k);
    }
}

bool take_pre_range_capture(DeviceState& d, ClusterBuildCapture& capture) {
    PreRangeStore& s = store_of(d);
    std::unique_lock lock(s.mutex);
    if (!s.submissions.count(capture.submission_index)) return false;
    const CaptureKey key{capture.submission_index, capture.pause_id, capture.occurrence};
    if (s.clusters.expects(key)) {
        // Completing a served capture walks its outputs: not under the lock the queue's
        // submissions take.
        lock.unlock();
        prepare_kept_cluster_capture(capture);
        lock.lock();
        if (!s.written) s.clusters.arrived(key, std::move(capture));
        s.arrived.notify_all();
        return true;
    }
    auto it = s.kept.find({capture.submission_index, capture.pause_id, capture.occurrence});
    if (it != s.kept.end() && !s.written) {
        it->second.capture = std::move(capture);
        s.arrived.notify_all();
    }
    return true;
}

void forget_pre_range_structure(DeviceState& d, uint64_t acceleration_structure) {
    PreRangeStore& s = store_of(d);
    std::lock_guard lock(s.mutex);
    if (!s.written) supersede(s, acceleration_structure);
}

void forget_pre_range_memory(DeviceState& d, uint64_t memory) {
    PreRangeStore& s = store_of(d);
    std::lock_guard lock(s.mutex);
    if (s.written) return;
    std::set<uint64_t> gone;
    for (const auto& [key, k] : s.kept)
        if (k.memories.count(memory)) gone.insert(k.current.begin(), k.current.end());
    for (uint64_t structure : gone) supersede(s, structure);
}

bool pre_range_prelude_due(DeviceState& d) {
    PreRangeStore& s = store_of(d);
    std::lock_guard lock(s.mutex);
    if (s.written || (s.kept.empty() && s.clusters.size() == 0)) {
        s.written = true;  // the range started: nothing more is kept
        return false;
    }
    return true;
}

void write_pre_range_prelude(DeviceState& d, const SubmissionRecord& captured, uint64_t index) {
    PreRangeStore& s = store_of(d);
    std::unique_lock lock(s.mutex);
    if (s.written) return;
    wait_for_captures(s, lock);
    s.written = true;
    d.sink->pre_range_state_written(marker_of(s, captured, index));

    RecordedCommandBuffer cb;
    cb.command_buffer = kPreRangeCommandBuffer;
    cb.usage = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
    std::vector<ClusterBuildCapture> captures;
    // Each command after a full barrier, with a fresh pause id: unique within the prelude. None
    // for a command whose capture did not come, so the sink does not wait for it.
    const auto next_pause_id = [&](std::optional<ClusterBuildCapture>& capture) -> uint64_t {
        if (!cb.commands.empty()) cb.commands.push_back(full_barrier());
        if (!capture) return 0;
        capture->pause_id = ++d.pause_counter;
        capture->occurrence = 0;
        capture->submission_index = index;
        capture->command_buffer = kPreRangeCommandBuffer;
        captures.push_back(std::move(*capture));
        return captures.back().pause_id;
    };
    // Cluster objects first: a KHR top level may name a cluster BLAS.
    for (PreRangeClusterCommands::Taken& t : s.clusters.take()) {
        t.command.pause_id = next_pause_id(t.capture);
        cb.commands.push_back(std::move(t.command));
    }
    for (KeptCommand* k : prelude_order(s)) {
        pause_id_in(k->command) = next_pause_id(k->capture);
        cb.commands.push_back(std::move(k->command));
    }
    s.kept.clear();
    lock.unlock();
    d.sink->command_buffer_recorded(cb);
    for (ClusterBuildCapture& c : captures) d.sink->cluster_build_captured(std::move(c));
    SubmissionRecord prelude;
    prelude.index = index;
    prelude.queue = captured.queue;
    prelude.queue_family = captured.queue_family;
    prelude.queue_index = captured.queue_index;
    prelude.synchronization2 = true;
    prelude.batches.push_back({{}, {kPreRangeCommandBuffer}, {}});
    d.sink->queue_submitted(prelude);
    HostSyncRecord idle;
    idle.kind = HostSyncRecord::Kind::kDeviceWaitIdle;
    d.sink->host_synchronized(idle);
}

}  // namespace clastrace::capture
