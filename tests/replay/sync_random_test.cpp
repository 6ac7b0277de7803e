// SPDX-License-Identifier: Apache-2.0
// Random streams: the interval model against the brute-force reference, and long valid
// streams that must stay silent.
#include <gtest/gtest.h>

#include <cstdio>
#include <random>
#include <string>

#include "reference_sync_model.h"
#include "sync_stream.h"

namespace clastrace::replay::test {
namespace {

constexpr StageMask kAccessStages[] = {VK_PIPELINE_STAGE_2_COPY_BIT,
                                       VK_PIPELINE_STAGE_2_CLEAR_BIT,
                                       VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT,
                                       VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                                       VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_COPY_BIT_KHR,
                                       VK_PIPELINE_STAGE_2_RAY_TRACING_SHADER_BIT_KHR};

struct AccessKind {
    StageMask stage;
    AccessMask access;
    bool write;
};
constexpr AccessKind kAccessKinds[] = {
    {VK_PIPELINE_STAGE_2_COPY_BIT, VK_ACCESS_2_TRANSFER_READ_BIT, false},
    {VK_PIPELINE_STAGE_2_COPY_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT, true},
    {VK_PIPELINE_STAGE_2_CLEAR_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT, true},
    {VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, VK_ACCESS_2_SHADER_STORAGE_READ_BIT, false},
    {VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT, true},
    {VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, VK_ACCESS_2_UNIFORM_READ_BIT, false},
    {VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
     VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT, false},
    {VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
     VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR, false},
    {VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
     VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR, true},
    {VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
     VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR |
         VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR,
     true},
    {VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_COPY_BIT_KHR,
     VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR, true},
    {VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_COPY_BIT_KHR, VK_ACCESS_2_TRANSFER_READ_BIT, false},
    {VK_PIPELINE_STAGE_2_RAY_TRACING_SHADER_BIT_KHR,
     VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR, false},
    {VK_PIPELINE_STAGE_2_RAY_TRACING_SHADER_BIT_KHR, VK_ACCESS_2_SHADER_STORAGE_READ_BIT, false},
};

constexpr StageMask kBarrierStages[] = {VK_PIPELINE_STAGE_2_COPY_BIT,
                                        VK_PIPELINE_STAGE_2_CLEAR_BIT,
                                        VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT,
                                        VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                                        VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_COPY_BIT_KHR,
                                        VK_PIPELINE_STAGE_2_RAY_TRACING_SHADER_BIT_KHR,
                                        VK_PIPELINE_STAGE_2_DRAW_INDIRECT_BIT,
                                        VK_PIPELINE_STAGE_2_ALL_TRANSFER_BIT,
                                        VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT,
                                        VK_PIPELINE_STAGE_2_TOP_OF_PIPE_BIT,
                                        VK_PIPELINE_STAGE_2_BOTTOM_OF_PIPE_BIT,
                                        VK_PIPELINE_STAGE_2_FRAGMENT_SHADER_BIT,
                                        VK_PIPELINE_STAGE_2_HOST_BIT};
constexpr AccessMask kBarrierAccesses[] = {0,
                                           VK_ACCESS_2_TRANSFER_WRITE_BIT,
                                           VK_ACCESS_2_SHADER_WRITE_BIT,
                                           VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR,
                                           VK_ACCESS_2_MEMORY_WRITE_BIT,
                                           VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT,
                                           VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR,
                                           VK_ACCESS_2_SHADER_READ_BIT,
                                           VK_ACCESS_2_TRANSFER_READ_BIT,
                                           VK_ACCESS_2_MEMORY_READ_BIT,
                                           VK_ACCESS_2_UNIFORM_READ_BIT,
                                           VK_ACCESS_2_HOST_READ_BIT};

// Drives SyncModel and the reference with the same random stream.
class RandomStream {
public:
    RandomStream(uint32_t seed, int queues, uint64_t address_space, bool host)
        : rng_(seed), queues_(queues), space_(address_space), host_(host) {}

    void run(int submissions, int ops_per_submission) {
        for (int s = 0; s < submissions; ++s) {
            const QueueId q = QueueId(pick(queues_));
            std::vector<SemaphoreWait> waits;
            std::vector<std::pair<uint64_t, StageMask>> ref_waits;
            for (auto it = pending_.begin(); it != pending_.end();) {
                if (chance(70)) {
                    const StageMask stages =
                        chance(50) ? VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT : barrier_stages();
                    waits.push_back({*it, 0, stages});
                    ref_waits.push_back({*it, stages});
                    it = pending_.erase(it);
                } else {
                    ++it;
                }
            }
            model.begin_submission(q, uint32_t(s), waits);
            reference.begin_submission(q, ref_waits);
            const int ops = 1 + pick(ops_per_submission);
            for (int i = 0; i < ops; ++i) one_op(q, uint32_t(s));
            std::vector<SemaphoreSignal> signals;
            std::vector<uint64_t> ref_signals;
            std::vector<StageMask> ref_stages;
            if (queues_ > 1 && chance(60)) {
                const uint64_t sem = next_semaphore_++;
                // vkQueueSubmit2 signals may narrow their first scope to some stages.
                const StageMask stages =
                    chance(30) ? barrier_stages() : StageMask(VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT);
                signals.push_back({sem, 0, stages});
                ref_signals.push_back(sem);
                ref_stages.push_back(stages);
                pending_.push_back(sem);
            }
            const uint64_t fence = host_ && chance(40) ? 500 + uint64_t(s) : 0;
            model.end_submission(signals, fence);
            reference.end_submission_with_fence(ref_signals, fence, ref_stages);
            if (fence) fences_.push_back(fence);
            if (host_) host_ops(q);
        }
    }

    // Between submissions: mapped-memory reads and writes, fence and idle waits.
    void host_ops(QueueId q) {
        for (int i = pick(3); i > 0; --i) {
            const int roll = pick(100);
            const uint32_t cmd = next_command_++;
            if (roll < 50) {
                const Access a{random_range(), 0, 0, chance(50), "mapped"};
                model.host_access({0, 0, 0, cmd, "host"}, a);
                reference.host_access(cmd, a);
            } else if (roll < 80 && !fences_.empty()) {
                const uint64_t f = fences_[std::size_t(pick(int(fences_.size())))];
                model.wait_for_fence(f);
                reference.wait_for_fence(f);
            } else if (roll < 93) {
                model.queue_wait_idle(q);
                reference.queue_wait_idle(q);
            } else {
                model.device_wait_idle();
                reference.device_wait_idle();
            }
        }
    }

    std::vector<ReferenceHazard> model_hazards() const {
        std::vector<ReferenceHazard> out;
        for (const HazardReport& h : model.hazards())
            out.push_back({h.prior.command.command, h.later.command.command, h.hazard,
                           h.overlap.begin, h.overlap.end});
        std::sort(out.begin(), out.end());
        return out;
    }

    SyncModel model{SyncOptions{1u << 20}};
    ReferenceSyncModel reference;

private:
    int pick(int n) { return int(rng_() % uint32_t(n)); }
    bool chance(int percent) { return pick(100) < percent; }
    StageMask barrier_stages() {
        StageMask m = kBarrierStages[pick(std::size(kBarrierStages))];
        if (chance(30)) m |= kBarrierStages[pick(std::size(kBarrierStages))];
        return m;
    }
    AccessMask barrier_access() {
        AccessMask m = kBarrierAccesses[pick(std::size(kBarrierAccesses))];
        if (chance(30)) m |= kBarrierAccesses[pick(std::size(kBarrierAccesses))];
        return m;
    }
    MemoryBarrier random_barrier() {
        if (chance(15))
            return {VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT, VK_ACCESS_2_MEMORY_WRITE_BIT,
                    VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT,
                    VK_ACCESS_2_MEMORY_READ_BIT | VK_ACCESS_2_MEMORY_WRITE_BIT};
        return {barrier_stages(), barrier_access(), barrier_stages(), barrier_access()};
    }
    AddressRange random_range() {
        const uint64_t begin = uint64_t(pick(int(space_) - 1));
        const uint64_t len = 1 + uint64_t(pick(std::min<int>(12, int(space_ - begin))));
        return {begin, begin + len};
    }
    // Two memory barriers, one buffer barrier, or a mix, in one command.
    void random_dependency(std::vector<MemoryBarrier>& mem, std::vector<BufferBarrier>& buf) {
        const int n = 1 + pick(2);
        for (int i = 0; i < n; ++i) {
            if (chance(40))
                buf.push_back({random_barrier(), random_range()});
            else
                mem.push_back(random_barrier());
        }
    }

    void one_op(QueueId q, uint32_t submission) {
        const uint32_t cmd = next_command_++;
        const CommandRef ref{submission, 0, 1, cmd, "cmd"};
        const int roll = pick(100);
        std::vector<MemoryBarrier> mem;
        std::vector<BufferBarrier> buf;
        const uint64_t event = q * 100 + uint64_t(pick(3));
        if (roll < 55) {
            const AccessKind& k = kAccessKinds[pick(std::size(kAccessKinds))];
            const AddressRange r = random_range();
            const Access a{r, k.stage, k.access, k.write, "f"};
            model.record_access(ref, a);
            reference.access(cmd, a);
        } else if (roll < 80) {
            // Often the very barrier recorded last: identical runs take a shortcut in the model.
            if (chance(40) && (!last_mem_.empty() || !last_buf_.empty())) {
                mem = last_mem_;
                buf = last_buf_;
            } else {
                random_dependency(mem, buf);
            }
            last_mem_ = mem;
            last_buf_ = buf;
            const DependencyInfo dep{mem, buf, 0};
            model.pipeline_barrier(ref, dep);
            reference.barrier(dep);
        } else if (roll < 88) {
            if (chance(25)) {
                const StageMask stages =
                    kBarrierStages[pick(std::size(kBarrierStages))] & 0xFFFFFFFFull;
                model.set_event_v1(ref, event, VkPipelineStageFlags(stages));
                const MemoryBarrier b{stages, 0, 0, 0};
                reference.set_event(event, DependencyInfo{std::span(&b, 1), {}, 0}, true);
            } else {
                random_dependency(mem, buf);
                const DependencyInfo dep{mem, buf, 0};
                model.set_event(ref, event, dep);
                reference.set_event(event, dep, false);
            }
        } else if (roll < 91) {
            model.reset_event(ref, event);
            reference.reset_event(event);
        } else {
            random_dependency(mem, buf);
            const DependencyInfo dep{mem, buf, 0};
            const uint64_t events[] = {event};
            model.wait_events(ref, events, dep);
            reference.wait_event(event, dep);
        }
    }

    std::mt19937 rng_;
    int queues_;
    uint64_t space_;
    uint32_t next_command_ = 0;
    uint64_t next_semaphore_ = 1000;
    std::vector<uint64_t> pending_;
    bool host_;
    std::vector<uint64_t> fences_;
    std::vector<MemoryBarrier> last_mem_;
    std::vector<BufferBarrier> last_buf_;
};

std::string describe(const std::vector<ReferenceHazard>& hs) {
    std::string s;
    for (const ReferenceHazard& h : hs)
        s += "  " + std::string(hazard_class_name(h.hazard)) + " cmd " +
             std::to_string(h.prior_command) + " -> " + std::to_string(h.later_command) + " [" +
             std::to_string(h.begin) + ", " + std::to_string(h.end) + ")\n";
    return s;
}

void cross_check(int queues, int seeds, int submissions, int ops, bool host = false) {
    uint64_t ordered = 0, unordered = 0;
    for (int seed = 1; seed <= seeds; ++seed) {
        RandomStream stream(uint32_t(seed * 7919 + queues + (host ? 1 : 0)), queues, 48, host);
        stream.run(submissions, ops);
        const auto got = stream.model_hazards();
        const auto want = stream.reference.hazards();
        if (got != want) {
            for (const HazardReport& h : stream.model.hazards())
                std::printf("%s\n", h.format().c_str());
        }
        ASSERT_EQ(got, want) << "seed " << seed << "\nmodel:\n"
                             << describe(got) << "reference:\n"
                             << describe(want);
        ordered += stream.reference.ordered_checks;
        unordered += stream.reference.unordered_checks;
    }
    // The streams must exercise both outcomes, or the comparison proves little.
    EXPECT_GT(ordered, uint64_t(seeds) * 5);
    EXPECT_GT(unordered, uint64_t(seeds) * 5);
    std::printf("%d queue(s)%s: %llu ordered and %llu unordered byte-pair decisions agreed\n",
                queues, host ? " + host" : "", (unsigned long long)ordered,
                (unsigned long long)unordered);
}

TEST(SyncRandom, OneQueueAgreesWithBruteForce) { cross_check(1, 400, 3, 25); }

TEST(SyncRandom, ThreeQueuesWithSemaphoresAgreeWithBruteForce) { cross_check(3, 400, 8, 4); }

TEST(SyncRandom, HostAccessesAndWaitsAgreeWithBruteForce) { cross_check(2, 400, 8, 4, true); }

TEST(SyncRandom, LongStreamsAgreeWithBruteForceAcrossCommandCollections) {
    // Hundreds of commands a stream: the model drops the commands no segment names any more
    // several times a stream (from 64 on; sync_model_internal.h, kCollectFloor).
    cross_check(2, 20, 30, 25, true);
}

TEST(SyncRandom, LongValidStreamHasNoFindings) {
    // Every access preceded by a full barrier: 200k accesses over 4 queues' worth of ranges, silent.
    Stream s;
    std::mt19937 rng(42);
    for (int sub = 0; sub < 100; ++sub) {
        s.submit();
        for (int i = 0; i < 2000; ++i) {
            s.full_barrier();
            const AccessKind& k = kAccessKinds[rng() % std::size(kAccessKinds)];
            const uint64_t begin = (rng() % 4096) * 64;
            s.model.record_access(
                s.next("cmd"),
                {{begin, begin + 64 + rng() % 4096}, k.stage, k.access, k.write, "f"});
        }
        s.end({}, 1);
        if (sub % 10 == 9) s.model.wait_for_fence(1);
    }
    EXPECT_TRUE(s.hazards().empty()) << s.hazards().front().format();
    EXPECT_EQ(s.model.stats().accesses, 200000u);
}

TEST(SyncRandom, LongLivedAccessKeepsItsCommandThroughCollections) {
    // A write that stays unordered while 100k reads of other commands come and go elsewhere:
    // the model drops the commands no segment names any more, and must still name the write's.
    Stream s;
    s.submit();
    s.model.record_access(s.next("vkCmdFillBuffer"),
                          Stream::write(0x40, 0x80, kClear, kTransferWrite, "first"));
    std::size_t bytes_at_10k = 0;
    for (uint32_t i = 0; i < 100000; ++i) {
        const uint64_t begin = 0x10000 + uint64_t(i % 512) * 0x100;
        s.model.record_access(s.next("vkCmdCopyBuffer"),
                              Stream::read(begin, begin + 0x40, kCopy, kTransferRead, "srcBuffer"));
        if (i == 10000) bytes_at_10k = s.model.memory_bytes();
    }
    s.model.record_access(s.next("vkCmdCopyBuffer"),
                          Stream::read(0x60, 0xA0, kCopy, kTransferRead, "last"));
    s.end();
    ASSERT_EQ(s.hazards().size(), 1u);
    const HazardReport& h = s.hazards()[0];
    EXPECT_EQ(h.hazard, HazardClass::kReadAfterWrite);
    EXPECT_EQ(h.prior.command.command, 0u);
    EXPECT_EQ(std::string(h.prior.command.name), "vkCmdFillBuffer");
    EXPECT_EQ(h.prior.field, "first");
    EXPECT_EQ(h.prior.range, (AddressRange{0x40, 0x80}));
    EXPECT_EQ(h.later.command.command, 100001u);
    EXPECT_EQ(h.later.field, "last");
    EXPECT_EQ(h.overlap, (AddressRange{0x60, 0x80}));
    // What is live stays the same, so the model's memory does too: without the commands
    // dropped, 90k more of them would be held.
    EXPECT_LE(s.model.memory_bytes(), bytes_at_10k + bytes_at_10k / 2);
}

TEST(SyncRandom, LongStreamWithoutBarriersFindsEveryConflictOnce) {
    // Writes to the same 64 bytes over and over without barriers: each consecutive pair is one WAW.
    Stream s;
    s.submit();
    for (int i = 0; i < 1000; ++i)
        s.model.record_access(s.next("vkCmdFillBuffer"),
                              Stream::write(0x100, 0x140, kClear, kTransferWrite, "dstBuffer"));
    s.end();
    EXPECT_EQ(s.hazards().size(), 999u);
    for (const HazardReport& h : s.hazards())
        EXPECT_EQ(h.later.command.command, h.prior.command.command + 1);
}

}  // namespace
}  // namespace clastrace::replay::test
