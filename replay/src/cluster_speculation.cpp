// SPDX-License-Identifier: Apache-2.0
#include "cluster_speculation.h"

#include "driver_sized_accesses.h"

#include <clastrace/common/enum_bits.h>
#include <clastrace/engine/build_sizes.h>
#include <clastrace/engine/execute.h>
#include <clastrace/traces/trace_generated.h>

#include <tbb/task_arena.h>

#include <algorithm>
#include <chrono>
#include <cstring>

namespace clastrace::replay::detail {

bool ClusterRunAhead::skip_checks_for_tests = false;

void RecentContents::keep(uint64_t hash, Bytes bytes) {
    if (!bytes || bytes->size() > max_bytes_ / 4) return;
    auto [it, fresh] = by_hash_.try_emplace(hash);
    if (!fresh) {
        order_.splice(order_.begin(), order_, it->second);
        return;
    }
    const size_t size = bytes->size();
    order_.emplace_front(hash, std::move(bytes));
    it->second = order_.begin();
    bytes_ += size;
    while (bytes_ > max_bytes_ && !order_.empty()) {
        bytes_ -= order_.back().second->size();
        by_hash_.erase(order_.back().first);
        order_.pop_back();
    }
}

RecentContents::Bytes RecentContents::find(uint64_t hash) {
    auto it = by_hash_.find(hash);
    if (it == by_hash_.end()) return nullptr;
    order_.splice(order_.begin(), order_, it->second);
    return it->second->second;
}

const RecentContents::Bytes* find_answer(std::span<const SnapshotAnswer> answers, size_t* next,
                                         uint64_t hash) {
    const size_t n = answers.size();
    for (size_t k = 0; k < n; ++k) {
        const size_t i = (*next + k) % n;
        if (answers[i].first == hash) {
            *next = i + 1;
            return &answers[i].second;
        }
    }
    return nullptr;
}

engine::RegionBytes ImageStoragePool::take(uint64_t size) {
    {
        std::lock_guard lock(mutex_);
        auto it = by_size_.find(size);
        if (it != by_size_.end() && !it->second.empty()) {
            engine::RegionBytes bytes = std::move(it->second.back());
            it->second.pop_back();
            kept_ -= bytes.resident_bytes();
            return bytes;
        }
    }
    return engine::RegionBytes(size);
}

void ImageStoragePool::image_opened() { most_images_ = std::max(most_images_, ++images_); }

void ImageStoragePool::image_given_back() { --images_; }

void ImageStoragePool::give(std::vector<engine::RegionBytes> storage) {
    std::lock_guard lock(mutex_);
    for (engine::RegionBytes& bytes : storage) {
        if (bytes.empty() || bytes.dense() || kept_ + bytes.resident_bytes() > kKeptBytes)
            continue;  // goes with `storage`, after the lock is released
        kept_ += bytes.resident_bytes();
        by_size_[bytes.size()].push_back(std::move(bytes));
    }
}

void RunBuffers::empty() {
    result = engine::ExecutionRecord{};
    directory = engine::ObjectDirectory{};
    lookups.addresses.clear();
    writes.clear();
    written.clear();
    written_regions.clear();
    reads.clear();
    read.clear();
    usage_queries.clear();
    built.clear();
}

std::unique_ptr<RunBuffers> RunBufferPool::take() {
    const bool on_replay_thread = std::this_thread::get_id() == replay_thread_;
    std::unique_ptr<RunBuffers> buffers;
    {
        std::lock_guard lock(mutex_);
        std::vector<std::unique_ptr<RunBuffers>>& kept = kept_[on_replay_thread];
        if (!kept.empty()) {
            buffers = std::move(kept.back());
            kept.pop_back();
        } else {
            ++made_;
        }
    }
    if (!buffers) buffers = std::make_unique<RunBuffers>();
    buffers->empty();  // what an earlier run on this side allocated
    buffers->on_replay_thread = on_replay_thread;
    return buffers;
}

void RunBufferPool::give(std::unique_ptr<RunBuffers> buffers) {
    if (!buffers) return;
    std::lock_guard lock(mutex_);
    kept_[buffers->on_replay_thread].push_back(std::move(buffers));
}

namespace {

// Op types whose ops read no object through the directory: their results depend on memory
// bytes alone, which commit checks.
bool reads_no_objects(VkClusterAccelerationStructureOpTypeNV type) {
    return type == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV ||
           type == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV;
}

// A cluster BLAS reads CLAS through the directory, which its run is given by the CLAS runs
// before it and commit checks entry by entry.
bool reads_clusters(VkClusterAccelerationStructureOpTypeNV type) {
    return type == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV;
}

// A move reads its sources through the directory too, and creates its destinations' entries.
bool moves_objects(VkClusterAccelerationStructureOpTypeNV type) {
    return type == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV;
}

// A move without noMoveOverlap retires its sources; commit lands created entries only, so such
// a move runs in its turn.
bool retires_sources(const VkClusterAccelerationStructureCommandsInfoNV& info) {
    return common::enum_bits(info.input.opType) ==
               VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV &&
           (!info.input.opInput.pMoveObjects || !info.input.opInput.pMoveObjects->noMoveOverlap);
}

engine::ObjectType built_type(const engine::OpResult& op) {
    return op.dst_type == 0   ? engine::ObjectType::kClustersBottomLevel
           : op.dst_type == 2 ? engine::ObjectType::kTriangleClusterTemplate
                              : engine::ObjectType::kTriangleCluster;
}

bool same_sizes(const ClusterDriverSizes& a, const ClusterDriverSizes& b) {
    return a.build_scratch_size == b.build_scratch_size &&
           a.acceleration_structure_size == b.acceleration_structure_size && a.queried == b.queried;
}

// The region of `image` holding [address, address + size) whole, or nullptr. `last` is tried
// first: ranges come in address order, most in the region of the range before.
const engine::MemoryRegion* region_holding(const engine::MemoryImage& image,
                                           const engine::MemoryRegion* last, uint64_t address,
                                           uint64_t size) {
    if (last && last->holds(address, size)) return last;
    const engine::MemoryRegion* r = image.find_region(address);
    return r && r->holds(address, size) ? r : nullptr;
}

// Sorts `ranges` and makes each run of overlapping or adjacent ones inside one region of `image`
// one range (the same bytes, fewer lookups and copies). False when a range lies in no region
// whole: it is left out.
bool merge_in_regions(RunBuffers::Ranges& ranges, const engine::MemoryImage& image) {
    std::sort(ranges.begin(), ranges.end());
    bool inside = true;
    size_t kept = 0;
    const engine::MemoryRegion* region = nullptr;  // the last kept range's
    for (size_t i = 0; i < ranges.size(); ++i) {
        const auto [address, size] = ranges[i];
        const engine::MemoryRegion* r = region_holding(image, region, address, size);
        if (!r) {
            inside = false;
            continue;
        }
        if (kept > 0 && r == region) {
            auto& [last_address, last_size] = ranges[kept - 1];
            if (address <= last_address + last_size) {
                last_size = std::max(last_address + last_size, address + size) - last_address;
                continue;
            }
        }
        ranges[kept++] = {address, size};
        region = r;
    }
    ranges.resize(kept);
    return inside;
}

// Copies the bytes of `ranges` (each inside one region of `image`: merge_in_regions kept them)
// one after another into `out`, telling `on_region` the region of each.
template <class OnRegion>
void copy_ranges(const engine::MemoryImage& image, const RunBuffers::Ranges& ranges,
                 std::vector<uint8_t>& out, OnRegion on_region) {
    uint64_t total = 0;
    for (const auto& range : ranges) total += range.second;
    out.resize(total);
    uint8_t* to = out.data();
    const engine::MemoryRegion* r = nullptr;
    for (const auto& [address, size] : ranges) {
        r = region_holding(image, r, address, size);
        std::memcpy(to, r->bytes.data() + (address - r->base), size);
        to += size;
        on_region(*r);
    }
}

// Whether two sorted lists of disjoint ranges share a byte (or a range of `b` starts inside
// one of `a`).
bool any_overlap(const RunBuffers::Ranges& a, const RunBuffers::Ranges& b) {
    size_t j = 0;
    for (const auto& [address, size] : a) {
        while (j < b.size() && b[j].first + b[j].second <= address) ++j;
        if (j < b.size() && b[j].first < address + size) return true;
    }
    return false;
}

}  // namespace

std::shared_ptr<ClusterRunAhead> ClusterRunAhead::start(
    std::vector<uint8_t> record, uint64_t stream_index, const AheadInputs& in,
    std::vector<std::shared_ptr<ClusterRunAhead>> earlier, bool* not_placed_yet) {
    bool unplaced = false;
    const bool wait_for_placement = not_placed_yet != nullptr;
    if (!not_placed_yet) not_placed_yet = &unplaced;
    *not_placed_yet = false;
    const fbs::Record* r = flatbuffers::GetRoot<fbs::Record>(record.data());
    const auto* build = r->body_as_CmdBuildClusterAccelerationStructureIndirect();
    if (!build || !build->input()) return nullptr;
    const auto type =
        static_cast<VkClusterAccelerationStructureOpTypeNV>(build->input()->op_type());
    if (!reads_no_objects(type) && !reads_clusters(type) && !moves_objects(type)) return nullptr;
    std::shared_ptr<ClusterRunAhead> run(new ClusterRunAhead(in.storage, in.buffers));
    run->stream_index_ = stream_index;
    run->reads_objects_ = reads_clusters(type) || moves_objects(type);
    if (run->reads_objects_) {
        for (const auto& e : earlier) run->earlier_turns_.push_back(e->turn_passed_);
        run->earlier_ = std::move(earlier);
    }
    run->queried_max_count_ =
        in.queries.largest_count(build->input()->op_type(), build->input()->op_mode());
    run->properties_ = &in.properties;
    run->max_findings_per_rule_ = in.max_findings_per_rule;
    run->model_accesses_ = in.model_accesses;
    run->implicit_object_room_ = build->implicit_object_room();
    try {
        run->info_ = traces::cluster_commands_from_record(*build, run->op_inputs_);
        if (retires_sources(run->info_)) return nullptr;
        run->sizes_ = in.queries.sizes_for(run->info_.input, in.properties);
        if (!run->plan(*build, in, not_placed_yet)) return nullptr;
        if (wait_for_placement && *not_placed_yet) return nullptr;
    } catch (const std::exception&) {
        return nullptr;  // a record or region the replay's own run will report on
    }
    run->record_ = std::move(record);
    run->holds_image_ = true;
    in.storage.image_opened();
    // Enqueued, not spawned: a spawned task goes to the replay thread's own deque, where any
    // wait of that thread (a parallel loop of a command in its turn) would pick it up first.
    tbb::this_task_arena::enqueue([stage = run->stage_, raw = run.get()] {
        int queued = kQueued;
        if (!stage->compare_exchange_strong(queued, kRunning)) return;  // cancelled
        raw->run();
        stage->store(kDone);
        stage->notify_all();
    });
    return run;
}

ClusterRunAhead::ClusterRunAhead(ImageStoragePool& storage, RunBufferPool& pool)
    : storage_(storage), pool_(pool) {}

ClusterRunAhead::~ClusterRunAhead() {
    release_image();
    pool_.give(std::move(buffers_));
}

void ClusterRunAhead::wait_or_cancel() {
    int queued = kQueued;
    if (!stage_->compare_exchange_strong(queued, kCancelled))
        for (int now = stage_->load(); now == kRunning; now = stage_->load()) stage_->wait(now);
}

void ClusterRunAhead::release_image() {
    wait_or_cancel();
    if (holds_image_) storage_.image_given_back();
    holds_image_ = false;
}

void ClusterRunAhead::finish() {
    int queued = kQueued;
    if (stage_->compare_exchange_strong(queued, kRunning)) {
        run();
        stage_->store(kDone);
        stage_->notify_all();  // a later run's task may wait for this one
        return;
    }
    for (int now = stage_->load(); now == kRunning; now = stage_->load()) stage_->wait(now);
}

// The replay's regions do not overlap, so neither do the planned ones: the first found is the one.
const PlannedRegion* ClusterRunAhead::planned_holder(uint64_t address) {
    for (size_t i : recent_regions_)
        if (i < regions_.size() && address - regions_[i].base < regions_[i].size)
            return &regions_[i];
    for (size_t i = 0; i < regions_.size(); ++i)
        if (address - regions_[i].base < regions_[i].size) {
            recent_regions_[1] = recent_regions_[0];
            recent_regions_[0] = i;
            return &regions_[i];
        }
    return nullptr;
}

bool ClusterRunAhead::plan_region(const engine::MemoryImage& real, uint64_t address,
                                  uint64_t size) {
    if (address == 0) return false;
    const PlannedRegion* holder = planned_holder(address);
    if (!holder) {
        const engine::MemoryRegion* r = real.find_region(address);
        if (!r) return false;
        recent_regions_[1] = recent_regions_[0];
        recent_regions_[0] = regions_.size();
        holder = &regions_.emplace_back(PlannedRegion{r->base, r->size, r->usage, r->label});
    }
    return holder->size - (address - holder->base) >= size;
}

// The regions the command names directly or through its snapshots, and the snapshots' bytes.
bool ClusterRunAhead::plan(const fbs::CmdBuildClusterAccelerationStructureIndirect& build,
                           const AheadInputs& in, bool* not_placed_yet) {
    const engine::MemoryImage& real = in.memory.image();
    regions_.reserve(8);  // a cluster command names a handful of buffers
    for (uint64_t address :
         {info_.srcInfosArray.deviceAddress, info_.srcInfosCount, info_.scratchData,
          info_.dstImplicitData, info_.dstAddressesArray.deviceAddress,
          info_.dstSizesArray.deviceAddress})
        if (address != 0 && !plan_region(real, address, 0)) *not_placed_yet = true;
    if (build.inputs()) {
        snapshots_.reserve(build.inputs()->size());
        size_t next_answer = 0;
        for (const fbs::MemorySnapshot* s : *build.inputs()) {
            const std::optional<uint64_t> address =
                in.memory.snapshot_address(s->buffer(), s->offset(), s->address());
            const RecentContents::Bytes* answer = find_answer(in.answers, &next_answer, s->hash());
            if (!answer) return false;  // no answer: it runs in its turn
            RecentContents::Bytes bytes = *answer;
            // Its buffer not replayed yet: the replay plans it again once regions are added.
            if (!address || !plan_region(real, *address, bytes->size())) {
                *not_placed_yet = true;
                return false;
            }
            snapshots_.push_back({*address, std::move(bytes)});
        }
    }
    if (common::enum_bits(info_.input.opMode) ==
        VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV)
        plan_explicit_destinations(real);
    return true;
}

// Reads each entry from the last snapshot holding it, as laying the snapshots in order leaves it.
void ClusterRunAhead::plan_explicit_destinations(const engine::MemoryImage& real) {
    const VkStridedDeviceAddressRegionKHR& array = info_.dstAddressesArray;
    if (array.deviceAddress == 0) return;
    const uint64_t stride = array.stride ? array.stride : 8;
    const uint64_t count = std::min<uint64_t>(info_.input.maxAccelerationStructureCount, 4096);
    for (uint64_t i = 0; i < count; ++i) {
        const uint64_t at = array.deviceAddress + i * stride;
        if (at < array.deviceAddress) break;
        const PlannedSnapshot* holder = nullptr;
        for (const PlannedSnapshot& s : snapshots_)
            if (at >= s.address && at - s.address <= s.bytes->size() &&
                s.bytes->size() - (at - s.address) >= 8)
                holder = &s;
        if (!holder) continue;  // zeros in the run's image: no destination
        uint64_t destination = 0;
        std::memcpy(&destination, holder->bytes->data() + (at - holder->address), 8);
        plan_region(real, destination, 0);
    }
}

void ClusterRunAhead::make_image() {
    for (PlannedRegion& r : regions_)
        image_.add_region(r.base, r.size, r.usage, std::move(r.label), storage_.take(r.size));
    lay_in_earlier_runs();
    for (const PlannedSnapshot& s : snapshots_) {
        auto span = image_.write_bytes(s.address, s.bytes->size(), {"snapshot", -1});
        std::memcpy(span.data(), s.bytes->data(), s.bytes->size());
    }
    snapshots_.clear();  // the contents go back to the replay's keeping
}

void ClusterRunAhead::lay_in_earlier_runs() {
    for (const std::shared_ptr<ClusterRunAhead>& earlier : earlier_) {
        earlier->finish();  // an earlier run: never waits for this one
        if (earlier->failed_ || !earlier->buffers_) continue;  // failed, or cancelled
        const RunBuffers& from = *earlier->buffers_;
        const uint8_t* bytes = from.written.data();
        for (const auto& [address, size] : from.writes) {
            const uint8_t* these = bytes;
            bytes += size;
            // An init-capture: clang 14 (scripts/fuzz.sh's compiler) captures no structured binding.
            const auto holds = [at = address](const PlannedRegion& r) {
                return at - r.base < r.size;
            };
            const auto source =
                std::find_if(from.written_regions.begin(), from.written_regions.end(), holds);
            if (source == from.written_regions.end()) continue;
            const engine::MemoryRegion* target = image_.find_region(address);
            if (!target)
                target = &image_.add_region(source->base, source->size, source->usage,
                                            source->label, storage_.take(source->size));
            if (target->base != source->base || target->size != source->size) continue;
            std::memcpy(image_.write_bytes(address, size, {"run ahead", -1}).data(), these, size);
        }
        if (earlier->built_intact_)
            for (const RunBuffers::Built& b : from.built)
                buffers_->directory.copy_entry(from.directory, b.address);
    }
    earlier_.clear();  // their images go back to the pool once no one else holds them
}

void ClusterRunAhead::run() {
    buffers_ = pool_.take();
    RunBuffers& b = *buffers_;
    engine::ExecuteOptions options;
    options.properties = *properties_;
    options.directory = &b.directory;
    options.max_findings_per_rule = max_findings_per_rule_;
    options.queried_max_count = queried_max_count_;
    options.answered_sizes = sizes_.answered();
    options.implicit_object_room = implicit_object_room_;
    // Answered "yes" here and asked again of the replay's buffers at the command's turn.
    options.first_without_usage = [&b](uint64_t begin, uint64_t end, VkBufferUsageFlags usage) {
        std::lock_guard<std::mutex> lock(b.usage_mutex);
        b.usage_queries.push_back({begin, end, usage});
        return std::optional<uint64_t>();
    };
    try {
        make_image();
        image_.log_writes(&b.writes);
        b.directory.log_lookups(&b.lookups);
        const auto started = std::chrono::steady_clock::now();
        try {
            // Isolated: waiting in its parallel loop, this run must not take up another one,
            // which would hold it up while the replay thread may be waiting for it.
            b.result = tbb::this_task_arena::isolate(
                [&] { return engine::execute(info_, image_, options); });
        } catch (const std::exception&) {
            failed_ = true;  // the command's turn runs it again and reports the failure
        }
        image_.log_writes(nullptr);
        b.directory.log_lookups(nullptr);
        engine_ns_ = static_cast<uint64_t>(std::chrono::duration_cast<std::chrono::nanoseconds>(
                                               std::chrono::steady_clock::now() - started)
                                               .count());
        built_intact_ = !failed_ && built_objects(&b.built);
        if (!failed_) {
            keep_written_bytes();
            keep_read_bytes();
            make_model_accesses();
        }
    } catch (const std::exception&) {
        failed_ = true;  // a snapshot no region holds whole, or a run its turn runs in place
        built_intact_ = false;
    }
    // Back to the pool now, on this thread: the image's regions and their bookkeeping were
    // made here, and what the checks need of it is kept apart.
    storage_.give(image_.release_storage());
}

void ClusterRunAhead::keep_written_bytes() {
    RunBuffers& b = *buffers_;
    const engine::MemoryImage& image = image_;
    merge_in_regions(b.writes, image);  // the image handed out each of them: all inside
    copy_ranges(image, b.writes, b.written, [&](const engine::MemoryRegion& r) {
        const bool known = std::any_of(b.written_regions.begin(), b.written_regions.end(),
                                       [&](const PlannedRegion& k) { return k.base == r.base; });
        if (!known) b.written_regions.push_back({r.base, r.size, r.usage, r.label});
    });
}

// The reads it compares at its turn: every read access but the empty ones, merged. One outside
// its image (a fault) or over bytes it wrote (it would compare its own output, not its input)
// and the run cannot stand.
void ClusterRunAhead::keep_read_bytes() {
    RunBuffers& b = *buffers_;
    const engine::MemoryImage& image = image_;
    for (const engine::MemoryAccess& a : b.result.accesses)
        if (!a.is_write && a.end > a.begin) b.reads.emplace_back(a.begin, a.end - a.begin);
    if (!merge_in_regions(b.reads, image) || any_overlap(b.reads, b.writes)) {
        reads_unreadable_ = true;
        return;
    }
    copy_ranges(image, b.reads, b.read, [](const engine::MemoryRegion&) {});
}

// From the record the command's turn takes when the run stands, with the sizes commit checks
// are the turn's: the same accesses the turn would make (cluster_command.cpp), made here.
void ClusterRunAhead::make_model_accesses() {
    const RunBuffers& b = *buffers_;
    if (!model_accesses_ || reads_unreadable_ || !built_intact_ || !b.result.findings.empty() ||
        info_.input.opMode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV)
        return;
    const bool implicit =
        info_.input.opMode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
    sized_ =
        std::make_unique<DriverSizedAccesses>(b.result, implicit, std::vector<uint64_t>{}, sizes_);
}

bool ClusterRunAhead::earlier_turns_passed() const {
    return std::all_of(earlier_turns_.begin(), earlier_turns_.end(),
                       [](const auto& passed) { return *passed; });
}

bool ClusterRunAhead::reads_unchanged(const engine::MemoryImage& real) const {
    const uint8_t* then = buffers_->read.data();
    const engine::MemoryRegion* r = nullptr;
    for (const auto& [address, size] : buffers_->reads) {
        r = region_holding(real, r, address, size);
        if (!r || std::memcmp(r->bytes.data() + (address - r->base), then, size) != 0) return false;
        then += size;
    }
    return true;
}

// Every write lands in one region of the replay's memory, within its resident limit. The pages
// each write would touch first are counted only when the limit is near: a write of n bytes
// touches at most n bytes and two pages' worth of pages.
bool ClusterRunAhead::writes_fit(const engine::MemoryImage& real) const {
    const RunBuffers& b = *buffers_;
    const bool room = real.within_resident_limit(
        b.written.size() + b.writes.size() * 2 * engine::RegionBytes::kPageBytes);
    uint64_t added = 0;
    const engine::MemoryRegion* r = nullptr;
    for (const auto& [address, size] : b.writes) {
        r = region_holding(real, r, address, size);
        if (!r) return false;
        if (!room) added += r->bytes.untouched_bytes(address - r->base, size);
    }
    return room || real.within_resident_limit(added);
}

bool ClusterRunAhead::built_objects(std::vector<RunBuffers::Built>* objects) const {
    for (const engine::OpResult& op : buffers_->result.ops) {
        if (!op.executed || op.dst_address == 0) continue;
        const engine::ObjectType type = built_type(op);
        if (!buffers_->directory.lookup(image_, op.dst_address, type, false, {"run ahead", -1})
                 .found())
            return false;  // a later op of the command wrote over it
        objects->push_back({op.dst_address, op.dst_size, type});
    }
    return true;
}

bool ClusterRunAhead::stands(const ReplayMemory& memory, uint32_t queried_max_count,
                             const ClusterDriverSizes& sizes) const {
    if (skip_checks_for_tests) return !failed_;
    if (failed_ || reads_unreadable_ || !buffers_->result.findings.empty() ||
        queried_max_count != queried_max_count_ || !same_sizes(sizes, sizes_))
        return false;
    for (const RunBuffers::UsageQuery& q : buffers_->usage_queries)
        if (memory.first_without_usage(q.begin, q.end, q.usage)) return false;
    return reads_unchanged(memory.image()) && writes_fit(memory.image());
}

bool ClusterRunAhead::same_objects(const engine::ObjectDirectory& real) const {
    const RunBuffers& b = *buffers_;
    return std::all_of(b.lookups.addresses.begin(), b.lookups.addresses.end(),
                       [&](uint64_t address) { return real.same_entry(b.directory, address); });
}

bool ClusterRunAhead::commit(ReplayMemory& memory, engine::ObjectDirectory& directory,
                             uint32_t queried_max_count, const ClusterDriverSizes& sizes,
                             engine::ExecutionRecord* record, uint64_t* engine_ns,
                             std::optional<DriverSizedAccesses>* sized) {
    finish();
    if (!stands(memory, queried_max_count, sizes) || !built_intact_ ||
        (!skip_checks_for_tests && !same_objects(directory)))
        return false;
    engine::MemoryImage& real = memory.image();
    const RunBuffers& b = *buffers_;
    const uint8_t* from = b.written.data();
    for (const auto& [address, size] : b.writes) {
        auto to = real.write_bytes(address, size, {"run ahead", -1});
        std::memcpy(to.data(), from, size);
        from += size;
    }
    // In op order, as the engine's own run records them; the bytes just copied are the ones
    // its own directory hashed.
    for (const RunBuffers::Built& built : b.built) directory.copy_entry(b.directory, built.address);
    stood_ = true;
    std::swap(*record, buffers_->result);  // the vectors sized_ views keep their storage
    if (engine_ns) *engine_ns = engine_ns_;
    if (sized && sized_) sized->emplace(std::move(*sized_));
    return true;
}

void RunAheadWindow::add(std::shared_ptr<ClusterRunAhead> run) {
    if (!run->reads_objects()) {
        recent_builds_.push_back(run);
        if (recent_builds_.size() > capacity_) {  // memory stays bounded
            recent_builds_.pop_front();
            bottom_levels_.erase(bottom_levels_.begin(),
                                 bottom_levels_.lower_bound(
                                     recent_builds_.front()->stream_index()));
        }
        counts.most_builds_kept =
            std::max<uint64_t>(counts.most_builds_kept, recent_builds_.size());
    } else if (unstarted_bottom_levels_.erase(run->stream_index()) +
               unstarted_moves_.erase(run->stream_index())) {
        trim_recent_builds();
    }
    runs_.push_back(std::move(run));
}

void RunAheadWindow::note_bottom_level(uint64_t stream_index) {
    bottom_levels_.insert(stream_index);
    unstarted_bottom_levels_.insert(stream_index);
    trim_recent_builds();
}

void RunAheadWindow::note_move(uint64_t stream_index) { unstarted_moves_.insert(stream_index); }

void RunAheadWindow::replayed_before(uint64_t stream_index) {
    const auto passed = unstarted_bottom_levels_.lower_bound(stream_index);
    const auto moves_passed = unstarted_moves_.lower_bound(stream_index);
    if (passed == unstarted_bottom_levels_.begin() && moves_passed == unstarted_moves_.begin())
        return;
    unstarted_bottom_levels_.erase(unstarted_bottom_levels_.begin(), passed);
    unstarted_moves_.erase(unstarted_moves_.begin(), moves_passed);
    trim_recent_builds();
}

// builds_before(j) takes the runs after the BLAS record before j: a BLAS record still to be read
// comes after the last one noted, and one noted that may still start needs those after the one
// before it. builds_for_move(j) takes those after the BLAS record before the one before j: a
// move record still to be read, after the last BLAS record noted, needs those after the one
// before it, and one noted that may still start those its own record needs.
void RunAheadWindow::trim_recent_builds() {
    if (bottom_levels_.size() < 2) return;
    uint64_t needed_from = *std::next(bottom_levels_.rbegin()) + 1;
    if (!unstarted_bottom_levels_.empty()) {
        const auto at = bottom_levels_.lower_bound(*unstarted_bottom_levels_.begin());
        needed_from = std::min(needed_from, at == bottom_levels_.begin() ? 0 : *std::prev(at) + 1);
    }
    if (!unstarted_moves_.empty())
        needed_from = std::min(needed_from, move_needs_from(*unstarted_moves_.begin()));
    while (!recent_builds_.empty() && recent_builds_.front()->stream_index() < needed_from)
        recent_builds_.pop_front();
}

std::vector<std::shared_ptr<ClusterRunAhead>> RunAheadWindow::builds_between(
    uint64_t after, uint64_t before) const {
    std::vector<std::shared_ptr<ClusterRunAhead>> runs;
    for (const auto& run : recent_builds_)
        if (run->stream_index() >= after && run->stream_index() < before) runs.push_back(run);
    std::sort(runs.begin(), runs.end(),
              [](const auto& a, const auto& b) { return a->stream_index() < b->stream_index(); });
    return runs;
}

std::vector<std::shared_ptr<ClusterRunAhead>> RunAheadWindow::builds_before(
    uint64_t stream_index) const {
    auto previous = bottom_levels_.lower_bound(stream_index);
    return builds_between(previous == bottom_levels_.begin() ? 0 : *std::prev(previous) + 1,
                          stream_index);
}

uint64_t RunAheadWindow::move_needs_from(uint64_t stream_index) const {
    auto previous = bottom_levels_.lower_bound(stream_index);
    if (previous != bottom_levels_.begin()) --previous;  // the BLAS record just before it
    return previous == bottom_levels_.begin() ? 0 : *std::prev(previous) + 1;
}

std::vector<std::shared_ptr<ClusterRunAhead>> RunAheadWindow::builds_for_move(
    uint64_t stream_index) const {
    return builds_between(move_needs_from(stream_index), stream_index);
}

std::shared_ptr<ClusterRunAhead> RunAheadWindow::take(std::span<const uint8_t> record) {
    for (auto it = runs_.begin(); it != runs_.end(); ++it) {
        const std::vector<uint8_t>& bytes = (*it)->record();
        if (bytes.size() == record.size() &&
            std::memcmp(bytes.data(), record.data(), bytes.size()) == 0 &&
            (*it)->earlier_turns_passed()) {
            std::shared_ptr<ClusterRunAhead> run = std::move(*it);
            run->mark_turn_passed();
            runs_.erase(it);
            return run;
        }
    }
    return nullptr;
}

bool RunAheadWindow::holds(uint64_t stream_index) const {
    return std::any_of(runs_.begin(), runs_.end(),
                       [&](const auto& run) { return run->stream_index() == stream_index; });
}

void RunAheadWindow::drop_before(uint64_t index) {
    std::erase_if(runs_, [&](const auto& run) {
        if (run->stream_index() >= index) return false;
        run->release_image();  // recent_builds_ may still hold it
        return true;
    });
}

}  // namespace clastrace::replay::detail
