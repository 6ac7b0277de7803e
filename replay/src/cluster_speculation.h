// SPDX-License-Identifier: Apache-2.0
// Cluster builds run ahead of their turn (docs/replay.md "Threads"). A capture records the bytes
// a cluster command reads as it saw them (its input snapshots), so the command can run early,
// on another thread, on an image of its own: the regions it names, holding only its snapshots.
// A cluster BLAS build also reads the CLAS it references through the object directory, and a
// move the objects it moves: its run starts on an image that holds, besides its snapshots, what
// the CLAS runs started before it wrote, and a directory of the objects they built. At its turn, after replay laid its
// snapshots in and translated its addresses as always, the run is taken only when every byte it
// read is the same in the replay's memory now, it wrote nothing it read, every object it looked
// up has the same entry in the replay's directory, the buffers and size answers it was judged
// against are the same, and it found nothing; then its written bytes and built objects are
// copied over in one go. Anything else runs the command again, in place, as a one-thread replay
// does.
#pragma once

#include "cluster_size_queries.h"
#include "replay_memory.h"

#include <clastrace/engine/execution_record.h>
#include <clastrace/engine/memory_image.h>
#include <clastrace/engine/object_directory.h>
#include <clastrace/engine/properties.h>
#include <clastrace/replay/replayer.h>
#include <clastrace/traces/cluster_conversions.h>

#include <atomic>
#include <cstdint>
#include <deque>
#include <list>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <span>
#include <string>
#include <thread>
#include <unordered_map>
#include <utility>
#include <vector>

namespace clastrace::replay::detail {

struct DriverSizedAccesses;  // driver_sized_accesses.h

// Contents bytes by hash, least recently used dropped first: the record stage's answers
// (replayer_record_stage.h), so that a content several records name is asked of the reader
// once. Shared: a record and a run ahead keep the bytes they hold after they are dropped here.
class RecentContents {
public:
    using Bytes = std::shared_ptr<const std::vector<uint8_t>>;
    explicit RecentContents(uint64_t max_bytes) : max_bytes_(max_bytes) {}
    // Bytes larger than a quarter of the bound are not kept (they would push out the rest).
    void keep(uint64_t hash, Bytes bytes);
    Bytes find(uint64_t hash);  // null when not kept

private:
    using Entry = std::pair<uint64_t, Bytes>;
    std::list<Entry> order_;  // most recently used first
    std::unordered_map<uint64_t, std::list<Entry>::iterator> by_hash_;
    uint64_t bytes_ = 0, max_bytes_;
};

// The reader's answer for the contents of one of a record's snapshots, by hash (the record
// stage asks for them: replayer_record_stage.h).
using SnapshotAnswer = std::pair<uint64_t, RecentContents::Bytes>;
// A record's answers are in the order it names its snapshots (inputs, then outputs; one without
// an answer left out), and its snapshots are asked for in that order: the entry for `hash` is
// looked for from *next on, then from the start, and *next moves past it. Null when none.
const RecentContents::Bytes* find_answer(std::span<const SnapshotAnswer> answers, size_t* next,
                                         uint64_t hash);

// Region bytes that runs' images take over from earlier runs: mapping a region per run and
// unmapping it afterwards costs two system calls, a page fault per page written and, at the
// unmap, a TLB shootdown on every core the replay's threads run on. Reused bytes hold an earlier
// run's contents; a run reads only what it laid in or fails its checks (commit compares every
// byte it read), so stale bytes never reach the replay. Safe from any thread.
class ImageStoragePool {
public:
    // Bytes of exactly `size`, reused when one is kept; new (zeros) otherwise.
    engine::RegionBytes take(uint64_t size);
    // Keeps them while the pool's resident bytes stay under kKeptBytes; unmaps the rest.
    void give(std::vector<engine::RegionBytes> storage);

    // Runs started (whose task makes an image of its bytes) and not given back yet, and the most
    // at once: what the window keeps alive (ReplayOptions::RunAheadCounts::most_images).
    // Counted on the replay thread, so the count does not depend on the schedule.
    void image_opened();
    void image_given_back();
    uint64_t most_images() const { return most_images_; }

    // Enough for the regions of a window's worth of runs to come back without a new mapping;
    // more only holds pages that an earlier run touched (peak memory, issue 23).
    static constexpr uint64_t kKeptBytes = 16ull << 20;

private:
    std::mutex mutex_;
    std::unordered_map<uint64_t, std::vector<engine::RegionBytes>> by_size_;
    uint64_t kept_ = 0;  // resident bytes of what by_size_ holds
    uint64_t images_ = 0, most_images_ = 0;
};

// A region of the replay's memory a run names: bounds, usage and label, no bytes.
struct PlannedRegion {
    uint64_t base = 0, size = 0;
    VkBufferUsageFlags usage = 0;
    std::string label;
};

// What a run keeps from its task until it is dropped: its engine record, its directory and
// what its checks and a later BLAS run need. glibc gives each worker thread a heap arena of its
// own; state a worker allocated and the replay thread freed at the command's turn left every
// arena holding a window's worth of runs, and peak memory grew with the trace (issue 23). So
// these buffers come from the replay's pool and go back to it, and only a run's task empties
// them (at its start, on a worker): the replay thread never frees what a worker allocated,
// and what the pool holds is bounded by the runs alive at once.
struct RunBuffers {
    struct UsageQuery {
        uint64_t begin = 0, end = 0;
        uint32_t usage = 0;
    };
    struct Built {
        uint64_t address = 0, size = 0;
        engine::ObjectType type{};
    };
    using Ranges = std::vector<std::pair<uint64_t, uint64_t>>;  // (address, size)
    engine::ExecutionRecord result;
    engine::ObjectDirectory directory;
    engine::ObjectDirectory::LookupLog lookups;
    // What the image logged as written, then (at the task's end) those ranges merged: sorted,
    // and each run of overlapping or adjacent ranges inside one region made one range. The
    // command's turn copies and checks a few ranges instead of one per op and field.
    Ranges writes;
    // The bytes the image ended with at each of writes, one after the other, and the regions
    // holding them: what a later BLAS run lays in and the command's turn copies over.
    std::vector<uint8_t> written;
    std::vector<PlannedRegion> written_regions;
    // The ranges it read (result.accesses' reads), merged as writes are, and the bytes the image
    // held there, one after the other: kept so that the image can go back to the pool when the
    // task ends, and compared at the command's turn.
    Ranges reads;
    std::vector<uint8_t> read;
    std::mutex usage_mutex;
    std::vector<UsageQuery> usage_queries;  // all answered "every byte has the usage"
    std::vector<Built> built;               // what built_objects found
    bool on_replay_thread = false;          // filled there (RunBufferPool)
    void empty();
};

// RunBuffers lent to runs and taken back, safe from any thread. Holds at most as many as were
// ever lent at once (the window and the runs a BLAS run still starts on). A run no worker took
// up by its turn runs on the replay thread: it takes buffers that only such runs use, so that
// the replay thread empties only what it filled.
class RunBufferPool {
public:
    explicit RunBufferPool(std::thread::id replay_thread) : replay_thread_(replay_thread) {}
    // Empty buffers for a run on the calling thread.
    std::unique_ptr<RunBuffers> take();
    void give(std::unique_ptr<RunBuffers> buffers);
    // Buffers made so far (lent or kept): bounded by the runs alive at once, whatever the
    // trace's length (ReplayOptions::RunAheadCounts::run_buffers). Read without the lock.
    uint64_t made() const { return made_.load(std::memory_order_relaxed); }

private:
    std::thread::id replay_thread_;
    std::mutex mutex_;
    std::vector<std::unique_ptr<RunBuffers>> kept_[2];  // [filled on the replay thread]
    std::atomic<uint64_t> made_{0};
};

// What the replay knows when it starts a command ahead: its memory as of now (for the regions'
// bounds and snapshot addresses), the contents of the command's snapshots and the size answers.
struct AheadInputs {
    const ReplayMemory& memory;
    std::span<const SnapshotAnswer> answers;  // the record's (a snapshot without one: no run)
    const ClusterSizeQueries& queries;
    const engine::EngineProperties& properties;  // outlives the run
    ImageStoragePool& storage;                   // outlives the run
    RunBufferPool& buffers;                      // outlives the run
    uint32_t max_findings_per_rule = 64;
    // Hazards checked: the run also makes its record's accesses for the sync model
    // (driver_sized_accesses.h), which the command's turn would make otherwise.
    bool model_accesses = false;
};

class ClusterRunAhead {
public:
    // Plans the command of `record` (a CmdBuildClusterAccelerationStructureIndirect's Record
    // bytes) and queues it on the calling thread's arena, or nullptr when it cannot run ahead:
    // instantiations and template indices (their objects may come from commands in their
    // turn), moves that retire their sources (without noMoveOverlap), a snapshot whose contents
    // the reader did not answer or that no region holds. A cluster BLAS or a move reads the
    // writes and objects of `earlier` (runs of CLAS and template builds read before it): its
    // task waits for them, or runs those not started yet.
    // Planning (which regions, which snapshot bytes where) is the replay thread's; making the
    // image and running the engine are the task's. With `not_placed_yet` given, a build that
    // names a buffer (directly or by a snapshot) that no replayed region holds yet does not
    // start, and *not_placed_yet says so: planned again once regions are added, it may (its run
    // would fault there and run again in its turn). Without it, only a snapshot does that.
    static std::shared_ptr<ClusterRunAhead> start(
        std::vector<uint8_t> record, uint64_t stream_index, const AheadInputs& in,
        std::vector<std::shared_ptr<ClusterRunAhead>> earlier, bool* not_placed_yet = nullptr);
    // Waits for a run in progress, or cancels one not started; its buffers go back to the pool.
    ~ClusterRunAhead();
    // Waits or cancels the same, once its command's turn has passed or it was dropped. Its
    // image went back to the pool when its task ended (a later BLAS run lays in only the bytes
    // it wrote, kept apart); this counts it given back, on the replay thread.
    void release_image();

    const std::vector<uint8_t>& record() const { return record_; }
    bool stood() const { return stood_; }  // commit took it
    uint64_t stream_index() const { return stream_index_; }
    bool reads_objects() const { return reads_objects_; }  // a cluster BLAS build or a move
    // On the replay thread: whether the commands of the runs it starts on have had their turn.
    // Until then it is the run of a later record with the same bytes (a BLAS over the same
    // slot, next frame but one) and is not taken.
    bool earlier_turns_passed() const;
    void mark_turn_passed() { *turn_passed_ = true; }  // taken at its command's turn

    // At the command's turn, with its snapshots laid in and addresses translated: true when the
    // early run stands (the checks in the file comment); its bytes and objects then land in
    // `memory` and `directory`, its record is swapped into *record (an empty one: the turn
    // takes the run's record instead of a copy), its engine time goes to *engine_ns and, when
    // it made them (AheadInputs::model_accesses; not in explicit mode, whose spans the replay's
    // memory sizes), its record's accesses for the sync model to *sized.
    // A run no worker has started yet runs here first, so whether it stands does not depend on
    // the schedule.
    bool commit(ReplayMemory& memory, engine::ObjectDirectory& directory,
                uint32_t queried_max_count, const ClusterDriverSizes& sizes,
                engine::ExecutionRecord* record, uint64_t* engine_ns,
                std::optional<DriverSizedAccesses>* sized = nullptr);

    // The checks commit makes without landing anything (a test breaks them through this).
    static bool skip_checks_for_tests;

private:
    ClusterRunAhead(ImageStoragePool& storage, RunBufferPool& pool);
    // What the task needs to make its image: the replay's regions the command names and its
    // snapshots' bytes and addresses.
    struct PlannedSnapshot {
        uint64_t address = 0;
        RecentContents::Bytes bytes;
    };
    bool plan(const fbs::CmdBuildClusterAccelerationStructureIndirect& build, const AheadInputs& in,
              bool* not_placed_yet);
    // Plans the replay's region holding `address`, if any; true when it holds `size` bytes there.
    bool plan_region(const engine::MemoryImage& real, uint64_t address, uint64_t size);
    // The planned region holding `address`, or nullptr. Snapshots take turns between a few
    // buffers (a cluster's vertices, then its indices): the last two found are tried first.
    const PlannedRegion* planned_holder(uint64_t address);
    // Explicit destinations: the regions the snapshots' dstAddressesArray entries name.
    void plan_explicit_destinations(const engine::MemoryImage& real);
    void make_image();
    // What the earlier runs wrote, laid in before its own snapshots (as their commands run
    // before its own in queue order), and their objects in its directory.
    void lay_in_earlier_runs();
    // Copies the bytes its image ended with at every range it wrote (merged), and at every
    // range it read (merged), into its buffers, so that the image can go back when the task
    // ends. A read of bytes it wrote, or outside its image, leaves it unable to stand.
    void keep_written_bytes();
    void keep_read_bytes();
    // The sync model's accesses of its record, when asked for and the run may stand.
    void make_model_accesses();
    // Waits for a run in progress, or cancels one not started.
    void wait_or_cancel();
    // The task: the image, then the engine; once, on a worker or (not started by its turn) on
    // the replay thread or the task of a later run that reads it.
    void run();
    void finish();  // the run is done when this returns
    bool stands(const ReplayMemory& memory, uint32_t queried_max_count,
                const ClusterDriverSizes& sizes) const;
    bool reads_unchanged(const engine::MemoryImage& real) const;
    bool same_objects(const engine::ObjectDirectory& real) const;
    bool writes_fit(const engine::MemoryImage& real) const;
    // The objects it built, when each is intact in its own image (the task asks, at its end).
    bool built_objects(std::vector<RunBuffers::Built>* objects) const;

    // Where the run is; shared with the queued task, which may outlive a cancelled run.
    enum Stage : int { kQueued, kRunning, kDone, kCancelled };
    std::shared_ptr<std::atomic<int>> stage_ = std::make_shared<std::atomic<int>>(kQueued);
    ImageStoragePool& storage_;
    RunBufferPool& pool_;
    std::vector<uint8_t> record_;
    uint64_t stream_index_ = 0;
    traces::ClusterOpInputStorage op_inputs_;
    VkClusterAccelerationStructureCommandsInfoNV info_{};
    uint32_t queried_max_count_ = 0;
    ClusterDriverSizes sizes_;
    const engine::EngineProperties* properties_ = nullptr;
    uint32_t max_findings_per_rule_ = 64;
    bool model_accesses_ = false;
    std::unique_ptr<DriverSizedAccesses> sized_;  // made by the task, viewing its record
    uint64_t implicit_object_room_ = 0;
    std::vector<PlannedRegion> regions_;
    size_t recent_regions_[2] = {0, 0};  // indices into regions_ (planned_holder)
    std::vector<PlannedSnapshot> snapshots_;
    bool reads_objects_ = false;
    std::vector<std::shared_ptr<ClusterRunAhead>> earlier_;  // released once laid in
    // Set when the run is taken at its command's turn; the later runs on it keep a copy.
    // Both only on the replay thread.
    std::shared_ptr<bool> turn_passed_ = std::make_shared<bool>(false);
    std::vector<std::shared_ptr<const bool>> earlier_turns_;
    engine::MemoryImage image_;  // made and given back by the task
    bool holds_image_ = false;   // started and not given back yet (the pool counts it)
    // Taken by the task, given back when the run is dropped (a later BLAS run may still lay
    // in what it wrote after its turn).
    std::unique_ptr<RunBuffers> buffers_;
    uint64_t engine_ns_ = 0;
    bool failed_ = false;
    bool stood_ = false;
    bool built_intact_ = false;      // what built_objects found, on the task
    bool reads_unreadable_ = false;  // a range it read was outside its image, or written by it
};

// The commands started ahead and not yet taken, at most `capacity`.
class RunAheadWindow {
public:
    // Made on the replay thread.
    explicit RunAheadWindow(size_t capacity)
        : capacity_(capacity), buffers_(std::this_thread::get_id()) {}
    bool full() const { return runs_.size() >= capacity_; }
    void add(std::shared_ptr<ClusterRunAhead> run);
    bool holds(uint64_t stream_index) const;  // a run of the record at this index
    // A cluster BLAS build's record at `stream_index`, started or not (records are read in
    // stream order; a build may start later, at its own record).
    void note_bottom_level(uint64_t stream_index);
    // A cluster move's record at `stream_index` (noMoveOverlap or not), started or not.
    void note_move(uint64_t stream_index);
    // The records before `stream_index` were replayed: a BLAS build or a move among them that
    // has not started never will. Drops the CLAS and template runs no BLAS run can start on any more.
    void replayed_before(uint64_t stream_index);
    // The runs a cluster BLAS at `stream_index` starts on: the CLAS and template builds
    // started from the records between the BLAS record before it and its own (a BLAS over the
    // clusters built just before it, the usual order; a BLAS over older ones, or over a build
    // that starts after it, fails its checks and runs in its turn).
    std::vector<std::shared_ptr<ClusterRunAhead>> builds_before(uint64_t stream_index) const;
    // The runs a cluster move at `stream_index` starts on: the CLAS and template builds started
    // from the records after the BLAS record before the last one before it (a move compacts
    // the clusters a BLAS was just built over, the usual order; a move of older ones fails its
    // checks and runs in its turn).
    std::vector<std::shared_ptr<ClusterRunAhead>> builds_for_move(uint64_t stream_index) const;
    // A run of a record with these bytes (any: a run stands or not by the bytes it read);
    // nullptr when none.
    std::shared_ptr<ClusterRunAhead> take(std::span<const uint8_t> record);
    // Drops the runs of records read before stream index `index` (their command buffers were
    // not in the submission just replayed).
    void drop_before(uint64_t index);

    ImageStoragePool& storage() { return storage_; }
    RunBufferPool& buffers() { return buffers_; }

    ReplayOptions::RunAheadCounts counts;

private:
    size_t capacity_;
    ImageStoragePool storage_;  // before runs_: the runs give their bytes back as they go
    RunBufferPool buffers_;     // the same
    std::deque<std::shared_ptr<ClusterRunAhead>> runs_;
    // The latest CLAS and template runs, taken or not (at most capacity_), and the stream
    // indices of the BLAS records read since the oldest of them. A taken or dropped run has
    // given its image back: what it wrote is all that is kept.
    std::deque<std::shared_ptr<ClusterRunAhead>> recent_builds_;
    std::set<uint64_t> bottom_levels_;
    // The BLAS records noted whose run has not started and whose record is not replayed yet:
    // each may still start on the runs since the BLAS record before it.
    std::set<uint64_t> unstarted_bottom_levels_;
    // The same for the move records noted.
    std::set<uint64_t> unstarted_moves_;
    // Drops the recent builds that neither those nor a BLAS record still to be read can start
    // on: a run keeps its buffers (what it read and wrote, its record) while it is held, and a
    // window's worth of them was most of the memory runs ahead add (issue 23).
    void trim_recent_builds();
    // The first stream index of the recent builds a move at `stream_index` starts on.
    uint64_t move_needs_from(uint64_t stream_index) const;
    // The recent builds read at stream indices [after, before), in stream order.
    std::vector<std::shared_ptr<ClusterRunAhead>> builds_between(uint64_t after,
                                                                 uint64_t before) const;
};

}  // namespace clastrace::replay::detail
