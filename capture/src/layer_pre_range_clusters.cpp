// SPDX-License-Identifier: Apache-2.0
// Kept cluster commands before a frame range (layer_pre_range_clusters.h). The rule: a command
// goes once every object it wrote was written over by a later command (any overlap ends an
// object) and no kept command that reads cluster objects (a bottom level, an instantiation, a
// move) ran between it and that overwrite. A command whose capture names no object (its sizes
// unknown) stays, and so does one whose capture has not come yet.
#include "layer_pre_range_clusters.h"

#include <algorithm>
#include <cstring>
#include <iterator>

namespace clastrace::capture {
namespace {

// Operations whose inputs name cluster objects (CLASes, templates, move sources): an older
// object they may read stays while such a command is kept.
bool reads_cluster_objects(const ClusterBuildCommand& command) {
    switch (command.parameters.info.input.opType) {
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV:
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV:
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_INSTANTIATE_TRIANGLE_CLUSTER_NV: return true;
    default: return false;
    }
}

}  // namespace

// Its own copy of every range: a served capture's ranges are views into the engine's image,
// which would otherwise stay alive, whole, until the range starts.
void prepare_kept_cluster_capture(ClusterBuildCapture& capture) {
    if (capture.complete) std::exchange(capture.complete, nullptr)(capture);
    for (auto* list : {&capture.inputs, &capture.outputs})
        for (CapturedRange& r : *list) {
            if (!r.bytes.is_view()) continue;
            CapturedBytes owned;
            if (const size_t size = r.bytes.size())
                std::memcpy(owned.fill(size), r.bytes.data(), size);
            r.bytes = std::move(owned);
        }
    capture.held_bytes = 0;
}

bool writes_cluster_objects(const ClusterCommandParameters& parameters) {
    const VkClusterAccelerationStructureInputInfoNV& input = parameters.info.input;
    return input.opMode != VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_COMPUTE_SIZES_NV &&
           input.opType !=
               VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_GET_CLUSTER_TEMPLATE_INDICES_NV;
}

void PreRangeClusterCommands::note(const Key& key, ClusterBuildCommand command) {
    const uint64_t sequence = next_sequence_++;
    sequence_of_[key] = sequence;
    kept_[sequence].key = key;
    kept_[sequence].command = std::move(command);
}

void PreRangeClusterCommands::arrived(const Key& key, ClusterBuildCapture capture) {
    auto at = sequence_of_.find(key);
    if (at == sequence_of_.end()) return;
    const uint64_t sequence = at->second;
    sequence_of_.erase(at);
    auto it = kept_.find(sequence);
    if (it == kept_.end()) return;  // dropped meanwhile
    Kept& k = it->second;
    for (const CapturedRange& r : capture.outputs)
        if (r.role == MemoryRole::kDstObject && !r.bytes.empty())
            k.objects.push_back({r.address, r.address + r.bytes.size(), 0});
    k.capture = std::move(capture);
    for (const Freed& f : freed_) end_freed(k, sequence, f);
    // Captures may come out of execution order (several queues): compare both ways.
    for (auto& [other_sequence, other] : kept_) {
        if (other_sequence < sequence) overwrite(other, k, sequence);
        if (other_sequence > sequence) overwrite(k, other, other_sequence);
    }
    drop_overwritten();
}

void PreRangeClusterCommands::overwrite(Kept& older, const Kept& newer, uint64_t newer_sequence) {
    for (Object& o : older.objects)
        for (const Object& n : newer.objects)
            if (n.begin < o.end && o.begin < n.end &&
                (o.overwritten_by == 0 || newer_sequence < o.overwritten_by))
                o.overwritten_by = newer_sequence;
}

void PreRangeClusterCommands::freed(uint64_t begin, uint64_t end) {
    const Freed f{begin, end, next_sequence_++};  // a sequence of its own: after what ran so far
    freed_.push_back(f);
    for (auto& [sequence, k] : kept_) end_freed(k, sequence, f);
    drop_overwritten();
}

void PreRangeClusterCommands::end_freed(Kept& k, uint64_t sequence, const Freed& f) {
    if (f.sequence < sequence) return;  // the command wrote into memory allocated afterwards
    for (Object& o : k.objects)
        if (f.begin < o.end && o.begin < f.end &&
            (o.overwritten_by == 0 || f.sequence < o.overwritten_by))
            o.overwritten_by = f.sequence;
}

// Newest first, so a reader that goes no longer holds back what it read.
void PreRangeClusterCommands::drop_overwritten() {
    for (auto it = kept_.rbegin(); it != kept_.rend();) {
        const Kept& k = it->second;
        uint64_t last_use = 0;  // the command that overwrote its last object
        bool all_overwritten = !k.objects.empty();
        for (const Object& o : k.objects) {
            all_overwritten = all_overwritten && o.overwritten_by != 0;
            last_use = std::max(last_use, o.overwritten_by);
        }
        // (it.base() is the command after this one.)
        const bool read_meanwhile =
            all_overwritten &&
            std::any_of(it.base(), kept_.lower_bound(last_use), [](const auto& entry) {
                return reads_cluster_objects(entry.second.command);
            });
        if (all_overwritten && !read_meanwhile)
            it = std::make_reverse_iterator(kept_.erase(std::next(it).base()));
        else
            ++it;
    }
}

size_t PreRangeClusterCommands::arrived_count() const {
    return size_t(std::count_if(kept_.begin(), kept_.end(), [](const auto& entry) {
        return entry.second.capture.has_value();
    }));
}

std::vector<PreRangeClusterCommands::Key> PreRangeClusterCommands::still_to_come() const {
    std::vector<Key> keys;
    for (const auto& [sequence, k] : kept_)
        if (!k.capture) keys.push_back(k.key);
    return keys;
}

uint32_t PreRangeClusterCommands::live_objects() const {
    uint32_t live = 0;
    for (const auto& [sequence, k] : kept_) {
        if (k.objects.empty()) ++live;
        for (const Object& o : k.objects) live += o.overwritten_by == 0;
    }
    return live;
}

uint64_t PreRangeClusterCommands::bytes(bool outputs) const {
    uint64_t bytes = 0;
    for (const auto& [sequence, k] : kept_)
        if (k.capture)
            for (const CapturedRange& r : outputs ? k.capture->outputs : k.capture->inputs)
                bytes += r.bytes.size();
    return bytes;
}

std::vector<PreRangeClusterCommands::Taken> PreRangeClusterCommands::take() {
    std::vector<Taken> taken;
    for (auto& [sequence, k] : kept_)
        taken.push_back({k.key, std::move(k.command), std::move(k.capture)});
    kept_.clear();
    sequence_of_.clear();
    freed_.clear();
    return taken;
}

}  // namespace clastrace::capture
