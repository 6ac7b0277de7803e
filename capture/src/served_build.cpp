// SPDX-License-Identifier: Apache-2.0
#include "clastrace/capture/served_build.h"
#include "clastrace/common/hex.h"

#include "clastrace/capture/capture_cost.h"
#include "clastrace/capture/cluster_input_walker.h"
#include "clastrace/capture/cluster_limits.h"
#include "clastrace/capture/uncached_copy.h"

#include <clastrace/engine/build_sizes.h>
#include <clastrace/engine/execute.h>

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <exception>
#include <utility>

namespace clastrace::capture {
namespace {

using common::hex;

// An empty image whose region bytes go back to `pool` with its last owner.
std::shared_ptr<engine::MemoryImage> pooled_image(std::shared_ptr<ServedRegionPool> pool) {
    return std::shared_ptr<engine::MemoryImage>(new engine::MemoryImage,
                                                [pool =
                                                     std::move(pool)](engine::MemoryImage* image) {
                                                    if (pool) pool->give(image->release_storage());
                                                    delete image;
                                                });
}

// [offset, offset + size) of `b`'s host bytes into `to`: plain loads for cached memory,
// streaming loads for the rest (write-combined on most discrete GPUs).
void copy_from_host(const ServedBuffer& b, uint64_t offset, uint64_t size, uint8_t* to) {
    if (b.cached)
        std::memcpy(to, b.host + offset, size);
    else
        copy_from_uncached(to, b.host + offset, size);
}

// All of [address, address + size) lies inside `b` (no sum may wrap).
bool holds(const ServedBuffer& b, uint64_t address, uint64_t size) {
    return address >= b.address && address - b.address <= b.size &&
           size <= b.size - (address - b.address);
}

// The groups completeServedRecord reads besides those the command wrote into: the ones holding
// the address and size arrays, and those holding the objects the arrays name (an object the
// command did not write is still read as the memory holds it). With indirected fields, all.
std::vector<bool> groups_the_outputs_name(
    const VkClusterAccelerationStructureCommandsInfoNV& command, const ServedMemory& memory,
    uint32_t executed) {
    const size_t count = memory.groups().size();
    if (command.addressResolutionFlags != 0) return std::vector<bool>(count, true);
    std::vector<bool> keep(count, false);
    auto mark = [&](uint64_t address) {
        const size_t g = address ? memory.group_of(address) : count;
        if (g < count) keep[g] = true;
    };
    const VkStridedDeviceAddressRegionKHR& addresses = command.dstAddressesArray;
    const VkStridedDeviceAddressRegionKHR& sizes = command.dstSizesArray;
    mark(addresses.deviceAddress);
    mark(sizes.deviceAddress);
    if (addresses.deviceAddress == 0 || sizes.deviceAddress == 0) return keep;
    const engine::MemoryImage& image = memory.image();
    for (uint32_t i = 0; i < executed; ++i) {
        uint64_t address = 0;
        uint32_t size = 0;
        try {
            const engine::FieldRef where{"dst arrays", int64_t(i)};
            address = image.read<uint64_t>(
                engine::MemoryImage::strided_address(addresses, i, sizeof address, where), where);
            size = image.read<uint32_t>(engine::MemoryImage::strided_address(sizes, i, sizeof size,
                                                                             where),
                                        where);
        } catch (const engine::MemoryFault&) {
            return std::vector<bool>(count, true);  // the walk reads what it can: keep it all
        }
        if (address != 0 && size != 0 && address + size > address)
            for (size_t g = memory.group_of(address);
                 g < count && memory.groups()[g].base < address + size; ++g)
                keep[g] = true;
    }
    return keep;
}

}  // namespace

engine::RegionBytes ServedRegionPool::take(uint64_t size) {
    std::lock_guard lock(mutex_);
    ++taken_now_[size];
    auto it = by_size_.find(size);
    if (it == by_size_.end()) return {};
    engine::RegionBytes bytes = std::move(it->second);
    by_size_.erase(it);
    held_ -= size;
    return bytes;
}

void ServedRegionPool::give(std::vector<engine::RegionBytes> storage) {
    std::lock_guard lock(mutex_);
    for (engine::RegionBytes& bytes : storage) {
        // Dense regions (the heap fallback past vm.max_map_count) and what exceeds the bound are freed.
        if (bytes.empty() || bytes.dense() || held_ + bytes.size() > kMaxBytes) continue;
        held_ += bytes.size();
        const uint64_t size = bytes.size();
        by_size_.emplace(size, std::move(bytes));
    }
}

uint64_t ServedRegionPool::held_bytes() const {
    std::lock_guard lock(mutex_);
    return held_;
}

void ServedRegionPool::pause_ended() {
    std::lock_guard lock(mutex_);
    if (taken_now_.empty()) return;  // a pause that copied nothing says nothing of the next
    if (recent_.size() == kDemandPauses) recent_.erase(recent_.begin());
    recent_.push_back(std::move(taken_now_));
    taken_now_.clear();
}

std::optional<uint64_t> ServedRegionPool::size_short_of_demand() const {
    std::map<uint64_t, uint32_t> demand;
    for (const auto& pause : recent_)
        for (const auto& [size, count] : pause) demand[size] = std::max(demand[size], count);
    for (const auto& [size, count] : demand)
        if (by_size_.count(size) < count && held_ + size <= kMaxBytes) return size;
    return std::nullopt;
}

bool ServedRegionPool::make_one_ready() {
    std::optional<uint64_t> size;
    {
        std::lock_guard lock(mutex_);
        size = size_short_of_demand();
    }
    if (!size) return false;
    CostScope cost(CostPhase::kRegionsMadeReady);
    engine::RegionBytes bytes;
    try {
        bytes = engine::RegionBytes(*size);
    } catch (const std::bad_alloc&) {
        return false;
    }
    // One store a page faults it in here, between pauses, rather than inside the next one.
    std::byte* first = bytes.write_at(0, *size);
    for (uint64_t at = 0; at < *size; at += engine::RegionBytes::kPageBytes)
        first[at] = std::byte{0};
    std::vector<engine::RegionBytes> ready;
    ready.push_back(std::move(bytes));
    give(std::move(ready));
    return true;
}

ServedMemory::ServedMemory(std::vector<ServedBuffer> buffers,
                           std::shared_ptr<ServedRegionPool> pool)
    : pool_(std::move(pool)), buffers_(std::move(buffers)) {
    std::vector<const ServedBuffer*> sorted;
    for (const ServedBuffer& b : buffers_)
        if (b.address != 0 && b.size != 0 && b.host && b.address + b.size > b.address)
            sorted.push_back(&b);
    std::stable_sort(sorted.begin(), sorted.end(),
                     [](auto* a, auto* b) { return a->address < b->address; });
    for (const ServedBuffer* b : sorted) {
        if (groups_.empty() || b->address >= groups_.back().end)
            groups_.push_back({b->address, b->address, 0, {}});
        Group& g = groups_.back();
        g.end = std::max(g.end, b->address + b->size);
        g.usage |= b->usage;
        g.buffers.push_back(b);
    }
    reset();  // the first, empty image
}

size_t ServedMemory::group_of(uint64_t address) const {
    auto it = std::upper_bound(groups_.begin(), groups_.end(), address,
                               [](uint64_t a, const Group& g) { return a < g.base; });
    if (it == groups_.begin()) return groups_.size();
    --it;
    return address < it->end ? size_t(it - groups_.begin()) : groups_.size();
}

const ServedBuffer* ServedMemory::buffer_holding(VkDeviceAddress address, uint64_t size) const {
    const size_t g = group_of(address);
    if (g == groups_.size()) return nullptr;
    const std::vector<const ServedBuffer*>& buffers = groups_[g].buffers;  // by address, ascending
    for (auto it = buffers.rbegin(); it != buffers.rend(); ++it)
        if (holds(**it, address, size)) return *it;
    return nullptr;
}

void ServedMemory::copy(size_t group) {
    if (copied_[group]) return;
    CostScope cost(CostPhase::kPauseCopyIn);
    const Group& g = groups_[group];
    engine::RegionBytes lent = pool_ ? pool_->take(g.end - g.base) : engine::RegionBytes();
    // Counted apart: a copy into fresh bytes pays a page fault a page (the pool ran dry: the
    // images of records not yet written and freed hold its regions).
    std::optional<CostScope> fresh;
    if (lent.empty()) fresh.emplace(CostPhase::kPauseCopyInFresh);
    engine::MemoryRegion& region =
        image_->add_region(g.base, g.end - g.base, g.usage, "buffer " + hex(g.buffers[0]->buffer),
                           std::move(lent));
    for (const ServedBuffer* b : g.buffers) {
        copy_in(*b, 0, b->size,
                reinterpret_cast<uint8_t*>(region.bytes.write_at(b->address - g.base, b->size)));
        bytes_copied_ += b->size;
    }
    copied_[group] = true;
}

const uint8_t* ServedMemory::read(VkDeviceAddress address, uint64_t size) {
    // A walk reads many small ranges of few buffers (a cluster's indices, then its vertices):
    // the last buffer that answered usually answers again.
    const ServedBuffer* b = last_read_;
    if (!(b && holds(*b, address, size))) {
        b = buffer_holding(address, size);
        if (!b) return nullptr;
        last_read_ = b;
        last_group_ = group_of(address);
        last_group_bytes_ = nullptr;
    }
    if (!last_group_bytes_) {
        copy(last_group_);
        last_group_bytes_ = reinterpret_cast<const uint8_t*>(
            std::as_const(*image_).find_region(groups_[last_group_].base)->bytes.data());
    }
    return last_group_bytes_ + (address - groups_[last_group_].base);
}

bool ServedMemory::view(VkDeviceAddress address, uint64_t size, CapturedBytes* out) {
    const uint8_t* bytes = read(address, size);
    if (!bytes) return false;
    if (!out) return true;
    viewed_[last_group_] = true;
    *out = CapturedBytes::view(image_, bytes, size);
    return true;
}

void ServedMemory::keep_inputs_as_read(std::vector<CapturedRange>& inputs,
                                       const engine::ExecutionRecord* written) const {
    std::vector<std::pair<uint64_t, uint64_t>> writes;  // merged [begin, end), ascending
    if (written) {
        for (const engine::MemoryAccess& a : written->accesses)
            if (a.is_write && a.end > a.begin) writes.emplace_back(a.begin, a.end);
        std::sort(writes.begin(), writes.end());
        size_t kept = 0;
        for (const auto& w : writes)
            if (kept && w.first <= writes[kept - 1].second)
                writes[kept - 1].second = std::max(writes[kept - 1].second, w.second);
            else
                writes[kept++] = w;
        writes.resize(kept);
    }
    for (CapturedRange& r : inputs) {
        if (!r.bytes.views(image_.get())) continue;
        const uint64_t end = r.address + r.bytes.size();
        if (written) {
            auto after = std::upper_bound(writes.begin(), writes.end(),
                                          std::make_pair(r.address, UINT64_MAX));
            const bool overlaps = (after != writes.end() && after->first < end) ||
                                  (after != writes.begin() && std::prev(after)->second > r.address);
            if (!overlaps) continue;
        }
        const ServedBuffer* b = buffer_holding(r.address, r.bytes.size());
        if (!b) continue;  // (a view is only made inside one buffer)
        const size_t size = r.bytes.size();
        copy_in(*b, r.address - b->address, size, r.bytes.fill(size));
    }
}

void ServedMemory::copy_in(const ServedBuffer& b, uint64_t offset, uint64_t size,
                           uint8_t* to) const {
    copy_from_host(b, offset, size, to);
    if (overlay_) overlay_(b.address + offset, to, size);
}

ServedMemory::~ServedMemory() =
    default;  // (the image's bytes go back to the pool with its last owner)

std::shared_ptr<const engine::MemoryImage> ServedMemory::share(const std::vector<bool>* keep) {
    if (keep) {
        std::vector<engine::RegionBytes> unneeded;
        for (size_t g = 0; g < groups_.size(); ++g)
            if (copied_[g] && !(*keep)[g] && !viewed_[g]) {
                engine::RegionBytes bytes;
                if (image_->remove_region(groups_[g].base, &bytes))
                    unneeded.push_back(std::move(bytes));
            }
        if (pool_) pool_->give(std::move(unneeded));
    }
    std::shared_ptr<const engine::MemoryImage> shared = std::move(image_);
    reset();
    return shared;
}

void ServedMemory::reset() {
    last_group_bytes_ = nullptr;
    image_ = pooled_image(pool_);
    copied_.assign(groups_.size(), false);
    viewed_.assign(groups_.size(), false);
    bytes_copied_ = 0;
}

ServedExecution execute_served_build(const VkClusterAccelerationStructureCommandsInfoNV& command,
                                     std::span<const ServedBuffer> buffers,
                                     engine::ObjectDirectory& directory,
                                     const engine::EngineProperties& properties,
                                     std::vector<CapturedRange>* input_walk) {
    ServedMemory memory({buffers.begin(), buffers.end()});
    return execute_served_build(command, memory, directory, properties, input_walk);
}

namespace {

// The buffer groups an attempt copies into the engine's image.
class GroupSelection {
public:
    explicit GroupSelection(const ServedMemory& memory)
        : memory_(memory), selected_(memory.groups().size(), false) {}

    // Selects the group holding `address`; false when it was selected already or none holds it.
    bool select(uint64_t address) {
        const size_t g = address ? memory_.group_of(address) : selected_.size();
        if (g == selected_.size() || selected_[g]) return false;
        selected_[g] = true;
        return true;
    }
    void select_group(size_t g) { selected_[g] = true; }
    void select_all() { selected_.assign(selected_.size(), true); }
    bool all() const {
        return std::find(selected_.begin(), selected_.end(), false) == selected_.end();
    }
    bool operator[](size_t g) const { return selected_[g]; }
    size_t size() const { return selected_.size(); }

private:
    const ServedMemory& memory_;
    std::vector<bool> selected_;
};

// The buffers the command names itself, those its pointers lead to and those read already.
GroupSelection first_selection(const VkClusterAccelerationStructureCommandsInfoNV& command,
                               ServedMemory& memory, const std::vector<CapturedRange>* input_walk) {
    GroupSelection selection(memory);
    if (command.addressResolutionFlags != 0) {
        selection.select_all();  // indirected fields: the seeds do not name their targets
        return selection;
    }
    for (uint64_t seed :
         {command.srcInfosArray.deviceAddress, command.srcInfosCount, command.dstImplicitData,
          command.scratchData, command.dstAddressesArray.deviceAddress,
          command.dstSizesArray.deviceAddress})
        selection.select(seed);
    // The capture's pointer walk names most of the rest (index, vertex, geometry, reference
    // arrays; the clusters a reference array names), so one engine run usually suffices.
    DeviceMemoryReader read = [&](VkDeviceAddress address, uint64_t size, CapturedBytes* out,
                                  std::string& why) {
        const uint8_t* bytes = memory.read(address, size);
        if (!bytes) {
            why = "not inside one buffer";
            return false;
        }
        if (out)
            *out = CapturedBytes::borrow(bytes, size);  // (the walk ends before the engine runs)
        return true;
    };
    ClusterMemoryWalk walk;
    if (!input_walk) walk = walk_cluster_inputs(ClusterCommandParameters::copy_of(command), read);
    for (const CapturedRange& range : input_walk ? *input_walk : walk.ranges) {
        selection.select(range.address);
        if (range.role != MemoryRole::kClusterReferences) continue;
        for (size_t at = 0; at + 8 <= range.bytes.size(); at += 8) {
            uint64_t reference;
            std::memcpy(&reference, range.bytes.data() + at, 8);
            selection.select(reference);
        }
    }
    for (size_t g = 0; g < selection.size(); ++g)  // in the image already: more is never less exact
        if (memory.copied(g)) selection.select_group(g);
    return selection;
}

// Runs the command over the selected groups; every finding about an address in a group left
// out adds that group, and the command runs again from the same state (the directory is copied
// per attempt). A run without findings read only memory that was there, so it equals a run over
// all buffers; with findings left, the last run is over all buffers: exact either way.
void run_attempts(const VkClusterAccelerationStructureCommandsInfoNV& command, ServedMemory& memory,
                  engine::ObjectDirectory& directory, const engine::ExecuteOptions& base_options,
                  std::vector<CapturedRange>* input_walk, GroupSelection& selection,
                  ServedExecution& result) {
    engine::ExecuteOptions options = base_options;
    engine::ObjectDirectory attempt;
    for (bool last = false;;) {
        if (result.attempts > 0) memory.reset();  // the engine wrote into the last image
        for (size_t g = 0; g < selection.size(); ++g)
            if (selection[g]) memory.copy(g);
        result.bytes_copied_in = memory.bytes_copied();
        // Over every buffer no further attempt can follow: the device's directory itself.
        last = last || selection.all();
        if (!last) attempt = directory;
        options.directory = last ? &directory : &attempt;
        result.record = engine::execute(command, memory.image(), options);
        ++result.attempts;
        if (input_walk)
            memory.keep_inputs_as_read(*input_walk, &result.record);  // before the write-back
        if (last) return;
        if (result.record.findings.empty()) {
            directory = std::move(attempt);
            return;
        }
        bool grew = false;
        for (const engine::Finding& f : result.record.findings) grew |= selection.select(f.address);
        if (!grew) selection.select_all();
    }
}

// Back into every buffer that holds a written byte (aliases included: same memory or not, each
// view must show what the command wrote). Marks in `keep` the groups written.
void write_back(ServedMemory& memory, const GroupSelection& selection, std::vector<bool>* keep,
                ServedExecution& result) {
    const std::vector<ServedMemory::Group>& groups = memory.groups();
    const engine::MemoryImage& image = memory.image();
    for (const engine::MemoryAccess& access : result.record.accesses) {
        if (!access.is_write || access.end <= access.begin) continue;
        for (size_t g = memory.group_of(access.begin);
             g < groups.size() && groups[g].base < access.end; ++g) {
            if (!selection[g]) continue;
            if (keep) (*keep)[g] = true;
            for (const ServedBuffer* b : groups[g].buffers) {
                const uint64_t begin = std::max(access.begin, b->address);
                const uint64_t end = std::min(access.end, b->address + b->size);
                if (begin >= end) continue;
                const engine::MemoryRegion* region = image.find_region(begin);
                if (!region || end > region->base + region->size)
                    continue;  // the engine wrote only inside regions
                std::memcpy(b->host + (begin - b->address),
                            region->bytes.data() + (begin - region->base), end - begin);
                result.bytes_written_back += end - begin;
                if (std::find(result.written_memories.begin(), result.written_memories.end(),
                              b->memory) == result.written_memories.end())
                    result.written_memories.push_back(b->memory);
            }
        }
    }
}

}  // namespace

ServedExecution execute_served_build(const VkClusterAccelerationStructureCommandsInfoNV& command,
                                     ServedMemory& memory, engine::ObjectDirectory& directory,
                                     const engine::EngineProperties& properties,
                                     std::vector<CapturedRange>* input_walk,
                                     std::optional<uint32_t> output_entries,
                                     const AfterServedWriteBack& after_write_back,
                                     uint64_t implicit_object_room) {
    ServedExecution result;
    GroupSelection selection = first_selection(command, memory, input_walk);
    engine::ExecuteOptions options;
    options.properties = properties;
    options.implicit_object_room = implicit_object_room;
    try {
        run_attempts(command, memory, directory, options, input_walk, selection, result);
    } catch (const std::exception& e) {
        if (input_walk)
            memory.keep_inputs_as_read(*input_walk, nullptr);  // it may have written anything
        result.error = e.what();
        return result;
    }
    result.ran = true;

    // The capture's walk may count more entries than the engine ran (its own caps): both are kept.
    std::vector<bool> keep;
    if (output_entries)
        keep = groups_the_outputs_name(command, memory,
                                       std::max(result.record.op_count, *output_entries));
    write_back(memory, selection, output_entries ? &keep : nullptr, result);
    if (after_write_back) after_write_back(memory.image(), result.record);
    result.image = memory.share(output_entries ? &keep : nullptr);
    return result;
}

void complete_served_record(ClusterBuildCapture& record,
                            std::shared_ptr<const engine::MemoryImage> image,
                            const ClusterCommandParameters& parameters,
                            const ServedMemory& memory) {
    DeviceMemoryReader from_image = [&](VkDeviceAddress a, uint64_t s, CapturedBytes* o,
                                        std::string& why) {
        const engine::MemoryRegion* region = image->find_region(a);
        if (!region || a + s < a || a + s > region->base + region->size) {
            why = "outside the memory the served build reached";
            return false;
        }
        const auto* bytes =
            reinterpret_cast<const uint8_t*>(region->bytes.data()) + (a - region->base);
        if (o) *o = CapturedBytes::view(image, bytes, s);  // nothing writes the image any more
        return true;
    };
    ClusterMemoryWalk walk = walk_cluster_outputs(parameters, record.executed_count, from_image);
    record.outputs = std::move(walk.ranges);
    for (auto& issue : walk.issues) record.issues.push_back(std::move(issue));
    // Ranges come in runs through one buffer (a cluster's indices, its vertices, the objects):
    // the buffer that named the last range is tried first, unless a nested one could hold it.
    const ServedBuffer* last = nullptr;
    for (auto* list : {&record.inputs, &record.outputs})
        for (CapturedRange& r : *list) {
            if (r.address == 0) continue;
            const ServedBuffer* b =
                last && holds(*last, r.address, r.bytes.size()) ? last : nullptr;
            if (!b && (b = memory.buffer_holding(r.address, r.bytes.size())) != nullptr)
                last =
                    memory.groups()[memory.group_of(b->address)].buffers.size() == 1 ? b : nullptr;
            if (b) {
                r.buffer = b->buffer;
                r.buffer_offset = r.address - b->address;
            }
        }
}

bool served_cluster_build_sizes(const VkClusterAccelerationStructureInputInfoNV& input,
                                VkAccelerationStructureBuildSizesInfoKHR& sizes) {
    const engine::BuildSizes answer =
        engine::cluster_build_sizes(input, served_engine_properties());
    sizes.accelerationStructureSize = answer.acceleration_structure_size;
    sizes.buildScratchSize = answer.build_scratch_size;
    sizes.updateScratchSize = answer.update_scratch_size;
    return answer.findings.empty();
}

}  // namespace clastrace::capture
