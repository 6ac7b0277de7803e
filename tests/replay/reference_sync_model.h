// SPDX-License-Identifier: Apache-2.0
// A deliberately naive reference for SyncModel: it keeps the whole stream and decides every
// pair of accesses byte by byte, walking all operations between them (O(n^2) and worse).
// It shares only the stage/access mask expansions with the model; no lazy log, no address
// map, no visibility rectangles, no vector clocks.
#pragma once

#include <algorithm>
#include <cstdint>
#include <map>
#include <ostream>
#include <set>
#include <tuple>
#include <vector>

#include "clastrace/replay/sync_model.h"

namespace clastrace::replay::test {

struct ReferenceHazard {
    uint32_t prior_command;
    uint32_t later_command;
    HazardClass hazard;
    uint64_t begin, end;  // hull of the conflicting bytes
    auto key() const { return std::tie(prior_command, later_command, hazard, begin, end); }
    friend bool operator<(const ReferenceHazard& a, const ReferenceHazard& b) {
        return a.key() < b.key();
    }
    friend bool operator==(const ReferenceHazard& a, const ReferenceHazard& b) {
        return a.key() == b.key();
    }
};

inline void PrintTo(const ReferenceHazard& h, std::ostream* os) {
    *os << hazard_class_name(h.hazard) << " cmd " << h.prior_command << "->" << h.later_command
        << " [" << h.begin << "," << h.end << ")";
}

class ReferenceSyncModel {
public:
    void begin_submission(QueueId queue, std::vector<std::pair<uint64_t, StageMask>> waits) {
        queue_ = queue;
        for (auto [semaphore, stages] : waits) {
            auto it = pending_signal_.find(semaphore);
            if (it == pending_signal_.end()) continue;
            Op op;
            op.kind = Op::kWait;
            op.queue = queue;
            op.signal_op = it->second;
            op.wait_scope =
                destination_scope(stages) & all_device_stages();  // waits never reach HOST
            pending_signal_.erase(it);
            ops_.push_back(op);
        }
    }
    // `stages`: each signal's stage mask (vkQueueSubmit2); missing entries are ALL_COMMANDS.
    void end_submission(std::vector<uint64_t> signals, std::vector<StageMask> stages = {}) {
        for (std::size_t i = 0; i < signals.size(); ++i) {
            Op op;
            op.kind = Op::kSignal;
            op.queue = queue_;
            const StageMask scope =
                source_scope(i < stages.size() ? stages[i] : VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT) &
                all_device_stages();
            op.narrow = scope != all_device_stages();
            op.signal_scope = scope;
            pending_signal_[signals[i]] = ops_.size();
            ops_.push_back(op);
        }
    }
    void end_submission_with_fence(std::vector<uint64_t> signals, uint64_t fence,
                                   std::vector<StageMask> stages = {}) {
        end_submission(std::move(signals), std::move(stages));
        if (!fence) return;
        Op op;
        op.kind = Op::kSignal;
        op.queue = queue_;
        fence_op_[fence] = ops_.size();
        ops_.push_back(op);
    }
    void host_access(uint32_t command, const Access& a) {
        Op op;
        op.kind = Op::kAccess;
        op.queue = kHostQueue;
        op.command = command;
        op.range = a.range;
        op.stage = VK_PIPELINE_STAGE_2_HOST_BIT;
        op.atoms = a.is_write ? VK_ACCESS_2_HOST_WRITE_BIT : VK_ACCESS_2_HOST_READ_BIT;
        op.is_write = a.is_write;
        ops_.push_back(op);
    }
    void wait_for_fence(uint64_t fence) {
        auto it = fence_op_.find(fence);
        if (it == fence_op_.end()) return;
        Op op;
        op.kind = Op::kHostWait;
        op.queue = kHostQueue;
        op.signal_op = it->second;
        ops_.push_back(op);
    }
    void queue_wait_idle(QueueId q) {
        Op signal;
        signal.kind = Op::kSignal;
        signal.queue = q;
        ops_.push_back(signal);
        Op op;
        op.kind = Op::kHostWait;
        op.queue = kHostQueue;
        op.signal_op = ops_.size() - 1;
        ops_.push_back(op);
    }
    void device_wait_idle() {
        Op op;
        op.kind = Op::kHostWait;
        op.queue = kHostQueue;
        op.all = true;
        ops_.push_back(op);
    }

    void access(uint32_t command, const Access& a) {
        Op op;
        op.kind = Op::kAccess;
        op.queue = queue_;
        op.command = command;
        op.range = a.range;
        op.stage = atomic_stages(a.stage);
        op.atoms = atomic_accesses(a.access);
        op.is_write = a.is_write;
        ops_.push_back(op);
    }
    void barrier(const DependencyInfo& dep) { push_barriers(Op::kBarrier, dep, 0, false); }
    void set_event(uint64_t event, const DependencyInfo& dep, bool v1) {
        push_barriers(Op::kSetEvent, dep, event, v1);
    }
    void reset_event(uint64_t event) {
        Op op;
        op.kind = Op::kResetEvent;
        op.queue = queue_;
        op.event = event;
        ops_.push_back(op);
    }
    void wait_event(uint64_t event, const DependencyInfo& dep) {
        push_barriers(Op::kWaitEvent, dep, event, false);
    }

    std::vector<ReferenceHazard> hazards() const {
        std::map<std::tuple<uint32_t, uint32_t, HazardClass>, std::pair<uint64_t, uint64_t>> found;
        for (std::size_t j = 0; j < ops_.size(); ++j) {
            const Op& b = ops_[j];
            if (b.kind != Op::kAccess) continue;
            for (uint64_t x = b.range.begin; x < b.range.end; ++x) {
                // The last write to x, and the latest read per (queue, stage) since it.
                std::ptrdiff_t w = -1;
                for (std::size_t i = 0; i < j; ++i)
                    if (touches(ops_[i], x) && ops_[i].is_write) w = std::ptrdiff_t(i);
                // Host reads and reads a host wait proved finished are ordered before anything
                // later; they no longer stand between the write and later writes.
                std::map<std::pair<QueueId, StageMask>, std::size_t> reads;
                for (std::size_t i = std::size_t(w + 1); i < j; ++i)
                    if (touches(ops_[i], x) && !ops_[i].is_write && ops_[i].queue != kHostQueue &&
                        completion(i, j) == j)
                        reads[{ops_[i].queue, ops_[i].stage}] = i;
                auto add = [&](std::size_t prior, HazardClass c) {
                    auto key = std::make_tuple(ops_[prior].command, b.command, c);
                    auto [it, fresh] = found.try_emplace(key, x, x + 1);
                    if (!fresh) {
                        it->second.first = std::min(it->second.first, x);
                        it->second.second = std::max(it->second.second, x + 1);
                    }
                };
                auto decide = [&](bool ok, std::size_t prior, HazardClass c) {
                    ++(ok ? ordered_checks : unordered_checks);
                    if (!ok) add(prior, c);
                };
                if (b.is_write) {
                    for (auto [k, r] : reads)
                        decide(ordered(r, j, x, false), r, HazardClass::kWriteAfterRead);
                    if (reads.empty() && w >= 0)
                        decide(ordered(std::size_t(w), j, x, true), std::size_t(w),
                               HazardClass::kWriteAfterWrite);
                } else if (w >= 0) {
                    decide(ordered(std::size_t(w), j, x, true), std::size_t(w),
                           HazardClass::kReadAfterWrite);
                }
            }
        }
        std::vector<ReferenceHazard> out;
        for (const auto& [key, hull] : found)
            out.push_back(
                {std::get<0>(key), std::get<1>(key), std::get<2>(key), hull.first, hull.second});
        std::sort(out.begin(), out.end());
        return out;
    }

    // Per-byte decisions taken by hazards(): both must be common for a comparison to mean much.
    mutable uint64_t ordered_checks = 0, unordered_checks = 0;

private:
    struct Barrier {
        StageMask src, dst;
        AccessMask src_atoms, dst_atoms;
        bool global;
        AddressRange range;
        bool covers(uint64_t x) const { return global || (range.begin <= x && x < range.end); }
    };
    struct Op {
        enum Kind {
            kAccess,
            kBarrier,
            kSetEvent,
            kResetEvent,
            kWaitEvent,
            kWait,
            kSignal,
            kHostWait
        } kind = kAccess;
        bool all = false;  // kHostWait: vkDeviceWaitIdle
        QueueId queue = 0;
        uint32_t command = 0;
        AddressRange range;
        StageMask stage = 0;
        AccessMask atoms = 0;
        bool is_write = false;
        std::vector<Barrier> barriers;
        uint64_t event = 0;
        bool v1 = false;
        std::size_t signal_op = 0;
        StageMask wait_scope = 0;
        bool narrow = false;         // kSignal: a stage mask that leaves device stages out
        StageMask signal_scope = 0;  // kSignal: its first synchronization scope
    };
    struct PairState {
        StageMask chain = 0, avail = 0;
        std::set<std::pair<int, int>> visible;  // (stage bit, access bit)
        void make_visible(StageMask stages, AccessMask accesses) {
            for (int s = 0; s < 64; ++s)
                if (stages >> s & 1)
                    for (int a = 0; a < 64; ++a)
                        if (accesses >> a & 1) visible.insert({s, a});
        }
    };

    static bool touches(const Op& op, uint64_t x) {
        return op.kind == Op::kAccess && op.range.begin <= x && x < op.range.end;
    }
    static bool visible(const PairState& s, const Op& b) {
        const int stage = __builtin_ctzll(b.stage);
        for (int a = 0; a < 64; ++a)
            if ((b.atoms >> a & 1) && !s.visible.count({stage, a})) return false;
        return true;
    }

    // Does the signal at ops_[signal] happen after ops_[a] (directly or through other waits)?
    bool signal_covers(std::size_t signal, std::size_t a) const {
        const QueueId q = ops_[signal].queue;
        if (q == ops_[a].queue && signal > a) return true;
        for (std::size_t k = 0; k < signal; ++k)
            if (ops_[k].kind == Op::kWait && ops_[k].queue == q &&
                signal_covers(ops_[k].signal_op, a))
                return true;
        return false;
    }

    // The first host wait after ops_[a] and before ops_[b] that covers ops_[a], or b.
    std::size_t completion(std::size_t a, std::size_t b) const {
        for (std::size_t k = a + 1; k < b; ++k)
            if (ops_[k].kind == Op::kHostWait &&
                (ops_[k].all || signal_covers(ops_[k].signal_op, a)))
                return k;
        return b;
    }

    // Is ops_[a] ordered before ops_[b] (and, when `memory`, visible to it) for byte x?
    bool ordered(std::size_t a, std::size_t b, uint64_t x, bool memory) const {
        const Op& A = ops_[a];
        const Op& B = ops_[b];
        if (A.queue == kHostQueue)
            return true;  // host work precedes later submissions and host work
        const std::size_t done = completion(a, b);
        if (B.queue == kHostQueue) {
            if (done == b) return false;
            if (!memory || B.is_write) return true;
            // Host reads need the write visible to HOST/HOST_READ by what ran before the wait.
            return visible(walk(a, done, x, A.queue), B);
        }
        if (done < b) return true;
        const PairState s = walk(a, b, x, B.queue);
        return memory ? visible(s, B) : (s.chain & B.stage) != 0;
    }

    // The dependency state of access ops_[a] as seen from queue q just before ops_[b], for byte x.
    PairState walk(std::size_t a, std::size_t b, uint64_t x, QueueId q) const {
        const Op& A = ops_[a];
        const AccessMask writes = A.atoms & all_write_accesses();
        PairState s;
        struct Snapshot {
            bool in, avail, v1;
        };
        std::map<uint64_t, Snapshot> events;
        for (std::size_t k = a + 1; k < b; ++k) {
            const Op& op = ops_[k];
            if (op.queue != q) continue;
            const bool home = A.queue == q;
            switch (op.kind) {
            case Op::kBarrier: {
                PairState next = s;
                for (const Barrier& br : op.barriers) {
                    if (!br.covers(x)) continue;
                    const bool direct = home && (br.src & A.stage);
                    if (!direct && !(s.chain & br.src)) continue;
                    next.chain |= br.dst;
                    if (A.is_write &&
                        ((direct && (writes & br.src_atoms) == writes) || (s.avail & br.src))) {
                        next.avail |= br.dst;
                        next.make_visible(br.dst, br.dst_atoms);
                    }
                }
                s = next;
                break;
            }
            case Op::kSetEvent: {
                Snapshot snap{false, false, op.v1};
                for (const Barrier& br : op.barriers) {
                    if (!br.covers(x)) continue;
                    const bool direct = home && (br.src & A.stage);
                    if (!direct && !(s.chain & br.src)) continue;
                    snap.in = true;
                    if (A.is_write && ((direct && (op.v1 || (writes & br.src_atoms) == writes)) ||
                                       (s.avail & br.src)))
                        snap.avail = true;
                }
                events[op.event] = snap;
                break;
            }
            case Op::kResetEvent: events.erase(op.event); break;
            case Op::kWaitEvent: {
                auto it = events.find(op.event);
                if (it == events.end() || !it->second.in) break;
                PairState next = s;
                for (const Barrier& br : op.barriers) {
                    if (!br.covers(x)) continue;
                    next.chain |= br.dst;
                    if (!A.is_write || !it->second.avail) continue;
                    if (it->second.v1 && (writes & br.src_atoms) != writes) continue;
                    next.avail |= br.dst;
                    next.make_visible(br.dst, br.dst_atoms);
                }
                s = next;
                break;
            }
            case Op::kWait: {
                bool in = signal_covers(op.signal_op, a), available = true;
                const Op& sig = ops_[op.signal_op];
                if (in && sig.narrow) {
                    // Only what the signal's stages, or chains into them, hold at the signal.
                    const bool direct = sig.queue == A.queue && (A.stage & sig.signal_scope);
                    const PairState at_signal = walk(a, op.signal_op, x, sig.queue);
                    in = direct || (at_signal.chain & sig.signal_scope);
                    available = !A.is_write || direct || (at_signal.avail & sig.signal_scope);
                }
                if (in) {
                    s.chain |= op.wait_scope;
                    if (A.is_write && available) {
                        s.avail |= op.wait_scope;
                        s.make_visible(op.wait_scope, all_read_accesses() | all_write_accesses());
                    }
                }
                break;
            }
            default: break;
            }
        }
        return s;
    }

    void push_barriers(typename Op::Kind kind, const DependencyInfo& dep, uint64_t event, bool v1) {
        Op op;
        op.kind = kind;
        op.queue = queue_;
        op.event = event;
        op.v1 = v1;
        for (const MemoryBarrier& m : dep.memory_barriers)
            op.barriers.push_back({source_scope(m.src_stages),
                                   destination_scope(m.dst_stages),
                                   atomic_accesses(m.src_access),
                                   atomic_accesses(m.dst_access),
                                   true,
                                   {}});
        for (const BufferBarrier& bb : dep.buffer_barriers)
            op.barriers.push_back({source_scope(bb.masks.src_stages),
                                   destination_scope(bb.masks.dst_stages),
                                   atomic_accesses(bb.masks.src_access),
                                   atomic_accesses(bb.masks.dst_access), false, bb.range});
        ops_.push_back(std::move(op));
    }

    std::vector<Op> ops_;
    std::map<uint64_t, std::size_t> pending_signal_;
    std::map<uint64_t, std::size_t> fence_op_;
    QueueId queue_ = 0;
};

}  // namespace clastrace::replay::test
