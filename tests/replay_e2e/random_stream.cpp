// SPDX-License-Identifier: Apache-2.0
#include "random_stream.h"

#include "catalogue_scene.h"
#include "trace_script.h"

#include <algorithm>
#include <array>
#include <random>

namespace clastrace::test {

namespace {

using namespace catalogue;

constexpr uint64_t kArena = 0x10100000;  // 1 MiB: every implicit destination
constexpr uint64_t kArenaBuffer = 0xb0a0;
constexpr uint64_t kExplicitAddresses = kOut + 0x200;
constexpr uint32_t kSlots = 64;  // explicit objects: kDst (CLAS) and kDst2 (templates), 0x800 apart
constexpr uint64_t kSlot = 0x800;

enum class Kind { kBuild, kCopy, kClear, kDispatch };

struct KindMasks {
    uint64_t stage, writes, accesses;
};

KindMasks masks(Kind k) {
    switch (k) {
    case Kind::kBuild:
        return {VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR,
                VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT | VK_ACCESS_2_SHADER_READ_BIT |
                    VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR |
                    VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR};
    case Kind::kCopy:
        return {VK_PIPELINE_STAGE_2_COPY_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT,
                VK_ACCESS_2_TRANSFER_READ_BIT | VK_ACCESS_2_TRANSFER_WRITE_BIT};
    case Kind::kClear:
        return {VK_PIPELINE_STAGE_2_CLEAR_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT,
                VK_ACCESS_2_TRANSFER_WRITE_BIT};
    case Kind::kDispatch:
        return {VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT,
                VK_ACCESS_2_SHADER_STORAGE_READ_BIT | VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT};
    }
    return {};
}

class Generator {
public:
    Generator(const std::string& path, const RandomStreamOptions& o)
        : o_(o), rng_(o.seed), t_(path, device()) {
        add_buffers(t_);
        t_.buffer(kArenaBuffer, kArena, 1u << 20,
                  VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT |
                      VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR |
                      VK_BUFFER_USAGE_STORAGE_BUFFER_BIT,
                  0x1001, kArena - kBase);
        queue_ = queue_handle(0);
    }

    RandomStreamStats run() {
        while (stats_.cluster_ops < o_.min_cluster_ops) step();
        t_.submit(queue_, waits_);  // the last commands, on the queue the stream is on
        ++stats_.submissions;
        t_.finish();
        return stats_;
    }

private:
    uint64_t queue_handle(uint32_t i) const { return 0x9001 + i; }
    uint32_t below(uint32_t n) { return n ? uint32_t(rng_() % n) : 0; }
    bool chance(double p) { return std::uniform_real_distribution<double>(0, 1)(rng_) < p; }
    bool mutate() {
        if (o_.mutation_rate <= 0 || !chance(o_.mutation_rate)) return false;
        ++stats_.mutations;
        return true;
    }

    // The dependency from the previous command to the next one (of kind `next`).
    void depend(Kind next) {
        if (!has_prev_) return;
        if (mutate()) return;  // dropped: a hazard the replay must report, not crash on
        const KindMasks a = masks(prev_), b = masks(next);
        if (pending_event_) {
            // vkCmdWaitEvents2 must name the dependency vkCmdSetEvent2 set.
            t_.wait_event(pending_event_, a.stage, a.writes, VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT,
                          VK_ACCESS_2_MEMORY_READ_BIT | VK_ACCESS_2_MEMORY_WRITE_BIT);
            pending_event_ = 0;
            ++stats_.commands;
            return;
        }
        switch (below(4)) {
        case 0: t_.full_barrier(); break;
        default: t_.barrier(a.stage, a.writes, b.stage, b.accesses); break;
        }
        ++stats_.commands;
    }

    // After a command: sometimes an event set now, waited on right before the next command.
    void after(Kind kind) {
        prev_ = kind;
        has_prev_ = true;
        ++stats_.commands;
        if (chance(0.15)) {
            pending_event_ = 0xe000 + below(8);
            // The next command's kind is not known yet: the second scope is every stage and access.
            ++stats_.events;
            t_.set_event(pending_event_, masks(kind).stage, masks(kind).writes,
                         VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT,
                         VK_ACCESS_2_MEMORY_READ_BIT | VK_ACCESS_2_MEMORY_WRITE_BIT);
            ++stats_.commands;
        }
    }

    void end_submission() {
        if (pending_event_) {  // an event set without its wait: close it with a barrier instead
            pending_event_ = 0;
        }
        const uint32_t next_queue = below(o_.queues);
        const bool hop = queue_handle(next_queue) != queue_ || chance(0.3);
        const bool host = chance(0.1);
        std::vector<SemaphoreUse> signals;
        if (hop && has_prev_) {
            const uint64_t semaphore = 0x5e000 + ++semaphores_;
            const uint64_t stages =
                chance(0.5) ? masks(prev_).stage : uint64_t(VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT);
            signals.push_back({semaphore, 0, stages});
            ++stats_.semaphores;
            stats_.narrow_signals += stages != VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT;
            wait_ = {semaphore, 0, VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT};
        }
        const uint64_t fence = host ? 0xf000 + stats_.submissions : 0;
        t_.submit(queue_, waits_, signals, fence);
        ++stats_.submissions;
        waits_.clear();
        if (hop && has_prev_) {
            waits_.push_back(wait_);
            first_after_hop_ = true;
        }
        queue_ = queue_handle(next_queue);
        if (host) {
            t_.wait_fence(fence);
            // Everything before is complete: the host rewrites the infos (the next build lays its own).
            std::vector<uint8_t> bytes(256);
            for (uint8_t& b : bytes) b = uint8_t(rng_());
            t_.host_write(kInfos + 0x2000, bytes);
            ++stats_.host_writes;
            if (!mutate()) {
                waits_.clear();  // the host wait already ordered everything
                first_after_hop_ = true;
                has_prev_ = false;
            }
        }
    }

    void before(Kind kind) {
        if (first_after_hop_) {
            // A semaphore (or a host wait) ordered everything before: no barrier needed.
            first_after_hop_ = false;
            if (!waits_.empty() && chance(0.5)) waits_.back().stages = masks(kind).stage;
            return;
        }
        depend(kind);
    }

    void step() {
        switch (below(16)) {
        case 0: copy_infos(); break;
        case 1: clear_outputs(); break;
        case 2: update_count(); break;
        case 3: dispatch_vertices(); break;
        case 4:
        case 5: explicit_clusters(); break;
        case 6: explicit_templates(); break;
        case 7:
        case 8: instantiate_templates(); break;
        case 9: template_indices_of(); break;
        case 10:
        case 11: bottom_levels(); break;
        case 12: moves(); break;
        case 13: implicit_templates(); break;
        default: implicit_clusters(); break;
        }
        if (chance(0.1)) {
            end_submission();
        } else if (chance(0.1)) {
            t_.next_command_buffer();  // barriers and events order across command buffers of a batch
            ++stats_.command_buffers;
        }
    }

    // --- non-build commands ------------------------------------------------------------
    void copy_infos() {
        before(Kind::kCopy);
        std::vector<uint8_t> bytes(512);
        for (uint8_t& b : bytes) b = uint8_t(rng_());
        t_.copy(kStagingBuffer, 0, kInfosBuffer, 0x1000, bytes.size(), {{kStaging, bytes}});
        after(Kind::kCopy);
    }
    void clear_outputs() {
        before(Kind::kClear);
        t_.fill(kOutBuffer, 0, 0x200, 0);
        after(Kind::kClear);
    }
    void update_count() {
        before(Kind::kClear);
        t_.update(kInfosBuffer, kCount - kInfos, bytes_of(std::vector<uint32_t>{1 + below(64)}));
        after(Kind::kClear);
    }
    void dispatch_vertices() {
        before(Kind::kDispatch);
        ClusterCommand any = triangle_clusters(Destinations::kImplicit, 1);
        std::vector<uint8_t> vertices(any.inputs[0].bytes.begin(),
                                      any.inputs[0].bytes.begin() + 64 * 12);
        t_.dispatch(kGeometryBuffer, 0, vertices.size(), {{kVertices, vertices}});
        after(Kind::kDispatch);
    }

    // --- builds --------------------------------------------------------------------------
    void emit(ClusterCommand& c) {
        before(Kind::kBuild);
        if (mutate()) damage(c);
        c.emit(t_);
        after(Kind::kBuild);
        ++stats_.cluster_commands;
        if (c.info.input.opType <=
            VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_GET_CLUSTER_TEMPLATE_INDICES_NV)
            ++stats_.commands_by_op_type[c.info.input.opType];
        stats_.cluster_ops +=
            ops_in_memory_ ? std::min(ops_in_memory_, c.info.input.maxAccelerationStructureCount)
                           : c.info.input.maxAccelerationStructureCount;
        ops_in_memory_ = 0;
    }

    void damage(ClusterCommand& c) {
        switch (below(7)) {
        case 0:
            if (!c.infos.empty())
                c.infos[below(uint32_t(c.infos.size()))] ^= uint8_t(1u << below(8));
            break;
        case 1: c.info.srcInfosArray.stride = below(80); break;
        case 2:
            c.info.srcInfosCount = kCount;
            ops_in_memory_ = uint32_t(rng_());
            c.inputs.push_back({kCount, bytes_of(std::vector<uint32_t>{ops_in_memory_})});
            break;
        case 3: c.info.scratchData = kScratch + below(0x10000); break;
        case 4: c.info.dstImplicitData = rng_(); break;
        case 5: c.info.input.maxAccelerationStructureCount = uint32_t(rng_()); break;
        default: c.info.srcInfosArray.deviceAddress = kBase + below(0x200000); break;
        }
    }

    // Implicit destinations share the arena and the implicit address/size arrays.
    void implicit_outputs(ClusterCommand& c) {
        c.info.dstImplicitData = kArena;
        c.info.dstAddressesArray = {kOut, 8, c.info.input.maxAccelerationStructureCount * 8ull};
        c.info.dstSizesArray = {kSizes, 4, c.info.input.maxAccelerationStructureCount * 4ull};
    }
    void triangle_limits(ClusterCommand& c, uint32_t count) {
        c.triangles.maxTotalTriangleCount = 2 * count;
        c.triangles.maxTotalVertexCount = 4 * count;
    }
    // Explicit destinations at `count` consecutive slots of `arena` from a random one.
    uint32_t explicit_outputs(ClusterCommand& c, uint64_t arena, uint32_t count) {
        const uint32_t first = below(kSlots - count + 1);
        std::vector<uint64_t> addresses;
        for (uint32_t i = 0; i < count; ++i) addresses.push_back(arena + (first + i) * kSlot);
        c.inputs.erase(std::remove_if(c.inputs.begin(), c.inputs.end(),
                                      [](const InputSnapshot& s) { return s.address == kOut; }),
                       c.inputs.end());
        c.inputs.push_back({kExplicitAddresses, bytes_of(addresses)});
        c.info.dstAddressesArray = {kExplicitAddresses, 8, count * 8ull};
        return first;
    }
    template <class Info>
    void randomize_ids(ClusterCommand& c, uint32_t count) {
        for (uint32_t i = 0; i < count; ++i)
            edit_info<Info>(c, i, [&](Info& info) {
                info.clusterID = uint32_t(rng_() & 0x7FFFFFFFu);
                info.vertexBuffer = kVertices + 48ull * (i % 16);
            });
    }

    void implicit_clusters() {
        const uint32_t count = 1 + below(64);
        ClusterCommand c = triangle_clusters(Destinations::kImplicit, count);
        randomize_ids<TriangleInfo>(c, count);
        implicit_outputs(c);
        triangle_limits(c, count);
        if (chance(0.3)) {  // the count comes from memory
            c.info.srcInfosCount = kCount;
            ops_in_memory_ = 1 + below(count);
            c.inputs.push_back({kCount, bytes_of(std::vector<uint32_t>{ops_in_memory_})});
        }
        emit(c);
    }
    void implicit_templates() {
        const uint32_t count = 1 + below(64);
        ClusterCommand c = triangle_templates(Destinations::kImplicit, count);
        randomize_ids<TemplateInfo>(c, count);
        implicit_outputs(c);
        triangle_limits(c, count);
        emit(c);
    }
    // 1..16 objects that `make` builds into explicit destinations among the `live` slots of `arena`.
    template <class Info>
    void explicit_objects(ClusterCommand (*make)(Destinations, uint32_t), uint64_t arena,
                          std::array<bool, kSlots>& live) {
        const uint32_t count = 1 + below(16);
        ClusterCommand c = make(Destinations::kExplicit, count);
        randomize_ids<Info>(c, count);
        triangle_limits(c, count);
        const uint32_t first = explicit_outputs(c, arena, count);
        emit(c);
        for (uint32_t i = 0; i < count; ++i) live[first + i] = true;
    }
    void explicit_clusters() { explicit_objects<TriangleInfo>(triangle_clusters, kDst, clas_); }
    void explicit_templates() {
        explicit_objects<TemplateInfo>(triangle_templates, kDst2, templates_);
    }
    std::vector<uint32_t> live(const std::array<bool, kSlots>& slots) const {
        std::vector<uint32_t> out;
        for (uint32_t i = 0; i < kSlots; ++i)
            if (slots[i]) out.push_back(i);
        return out;
    }
    void instantiate_templates() {
        const std::vector<uint32_t> alive = live(templates_);
        if (alive.empty()) return explicit_templates();
        const uint32_t count = 1 + below(64);
        ClusterCommand c = instantiate(count);
        for (uint32_t i = 0; i < count; ++i)
            edit_info<InstantiateInfo>(c, i, [&](InstantiateInfo& info) {
                info.clusterTemplateAddress = kDst2 + alive[below(uint32_t(alive.size()))] * kSlot;
                info.vertexBuffer = {kVertices + 48ull * (i % 16), 12};
                info.clusterIdOffset = uint32_t(rng_() % 1000);
            });
        implicit_outputs(c);
        triangle_limits(c, count);
        emit(c);
    }
    void template_indices_of() {
        const std::vector<uint32_t> alive = live(templates_);
        if (alive.empty()) return explicit_templates();
        const uint32_t count = 1 + below(64);
        ClusterCommand c = template_indices(count);
        for (uint32_t i = 0; i < count; ++i)
            edit_info<VkClusterAccelerationStructureGetTemplateIndicesInfoNV>(
                c, i, [&](auto& info) {
                    info.clusterTemplateAddress =
                        kDst2 + alive[below(uint32_t(alive.size()))] * kSlot;
                });
        implicit_outputs(c);
        emit(c);
    }
    void bottom_levels() {
        std::vector<uint32_t> alive = live(clas_);
        if (alive.empty()) return explicit_clusters();
        const uint32_t count = 1 + below(16);
        ClusterCommand c = bottom_level();
        c.info.input.maxAccelerationStructureCount = count;
        c.info.srcInfosArray = {kInfos, sizeof(BottomLevelInfo), count * sizeof(BottomLevelInfo)};
        std::vector<BottomLevelInfo> infos(count);
        std::vector<uint64_t> references;
        uint32_t total = 0;
        for (uint32_t i = 0; i < count; ++i) {
            std::shuffle(alive.begin(), alive.end(), rng_);
            const uint32_t n = 1 + below(std::min<uint32_t>(8, uint32_t(alive.size())));
            infos[i] = BottomLevelInfo{n, 8, kReferences + references.size() * 8};
            for (uint32_t k = 0; k < n; ++k) references.push_back(kDst + alive[k] * kSlot);
            total += n;
        }
        c.infos = bytes_of(infos);
        c.inputs = {{kReferences, bytes_of(references)}};
        c.bottom_level.maxTotalClusterCount = total;
        c.bottom_level.maxClusterCountPerAccelerationStructure = 8;
        implicit_outputs(c);
        emit(c);
    }
    void moves() {
        const std::vector<uint32_t> alive = live(clas_);
        if (alive.empty()) return explicit_clusters();
        const uint32_t count = 1 + below(16);
        ClusterCommand c = move_clusters(count);
        std::vector<uint64_t> sources;
        for (uint32_t i = 0; i < count; ++i)
            sources.push_back(kDst + alive[below(uint32_t(alive.size()))] * kSlot);
        c.infos = bytes_of(sources);
        c.move.maxMovedBytes = 64ull * count * kSlot;
        implicit_outputs(c);
        emit(c);
    }

    RandomStreamOptions o_;
    std::mt19937_64 rng_;
    TraceScript t_;
    RandomStreamStats stats_;
    Kind prev_ = Kind::kBuild;
    bool has_prev_ = false;
    uint64_t pending_event_ = 0;
    uint64_t queue_ = 0;
    uint64_t semaphores_ = 0;
    bool first_after_hop_ = false;
    uint32_t ops_in_memory_ = 0;  // srcInfosCount's value for the command being emitted (0: none)
    SemaphoreUse wait_;
    std::vector<SemaphoreUse> waits_;
    std::array<bool, kSlots> clas_{};
    std::array<bool, kSlots> templates_{};
};

}  // namespace

RandomStreamStats write_random_stream(const std::string& path, const RandomStreamOptions& options) {
    Generator g(path, options);
    return g.run();
}

}  // namespace clastrace::test
