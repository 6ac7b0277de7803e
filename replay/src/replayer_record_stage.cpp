// SPDX-License-Identifier: Apache-2.0
#include "replayer_record_stage.h"

#include <clastrace/traces/records.h>

#include <algorithm>
#include <cstring>
#include <utility>

namespace clastrace::replay::detail {

void StageReturns::give_block(uint8_t* block) {
    {
        std::lock_guard lock(mutex_);
        if (!ended_) {
            blocks_.push_back(block);
            return;
        }
    }
    delete[] block;
}

void StageReturns::give(void* memory, Free free) {
    {
        std::lock_guard lock(mutex_);
        if (!ended_) {
            given_.emplace_back(memory, free);
            return;
        }
    }
    free(memory);
}

uint8_t* StageReturns::reuse_block() {
    uint8_t* block = nullptr;
    {
        std::lock_guard lock(mutex_);
        freeing_.swap(given_);  // the two lists' storage changes hands, never freed here
        if (!blocks_.empty()) {
            block = blocks_.back();
            blocks_.pop_back();
        }
    }
    for (auto [memory, free] : freeing_) free(memory);
    freeing_.clear();
    return block;
}

void StageReturns::stage_ended() {
    std::lock_guard lock(mutex_);
    ended_ = true;
    for (uint8_t* block : blocks_) delete[] block;
    for (auto [memory, free] : given_) free(memory);
    for (auto [memory, free] : freeing_) free(memory);
    blocks_.clear();
    given_.clear();
    freeing_.clear();
}

StageReturns::~StageReturns() { stage_ended(); }

const uint8_t* RecordBlocks::copy(const uint8_t* bytes, size_t size, Block* block) {
    const size_t room = (size + 15) & ~size_t(15);
    if (!block_ || used_ + room > capacity_) {
        if (room <= StageReturns::kBlockBytes) {
            uint8_t* reused = returns_->reuse_block();
            block_ = Block(
                reused ? reused : new uint8_t[StageReturns::kBlockBytes],
                [returns = returns_](uint8_t* b) { returns->give_block(b); },
                StageReturns::Allocator<uint8_t>(returns_));
            capacity_ = StageReturns::kBlockBytes;
        } else {  // a record larger than a block: rare, freed where it goes
            block_ = Block(new uint8_t[room]);
            capacity_ = room;
        }
        used_ = 0;
    }
    uint8_t* at = block_.get() + used_;
    used_ += room;
    std::memcpy(at, bytes, size);
    *block = block_;
    return at;
}

RecentContents::Bytes RecordStage::stage_bytes(const uint8_t* data, size_t size) {
    return RecentContents::Bytes(
        new std::vector<uint8_t>(data, data + size),
        [returns = returns_](const std::vector<uint8_t>* bytes) {
            returns->give(const_cast<std::vector<uint8_t>*>(bytes),
                          [](void* b) { delete static_cast<std::vector<uint8_t>*>(b); });
        },
        StageReturns::Allocator<uint8_t>(returns_));
}

RecordStage::RecordStage(traces::TraceReader& reader, std::mutex& reader_mutex)
    : reader_(reader), reader_mutex_(reader_mutex) {
    thread_ = std::thread([this] { loop(); });
}

RecordStage::~RecordStage() {
    {
        std::lock_guard lock(mutex_);
        stopping_ = true;
    }
    ready_changed_.notify_all();
    thread_.join();
    returns_->stage_ended();
}

bool RecordStage::read(StagedRecord* out) {
    {
        // The view is valid only until the reader's next call, which the replay thread may make
        // (read_contents) as soon as the lock is released: copy it first.
        std::lock_guard lock(reader_mutex_);
        traces::RecordView view;
        if (!reader_.next(&view)) return false;
        out->view = view;
        out->view.bytes = blocks_.copy(view.bytes, view.size, &out->block);
    }
    out->view.record = flatbuffers::GetRoot<fbs::Record>(out->view.bytes);
    resolve_snapshots(out);
    return true;
}

void RecordStage::resolve_snapshots(StagedRecord* out) {
    const traces::SnapshotLists lists = traces::record_snapshots(*out->view.record);
    if (!lists.inputs && !lists.outputs) return;
    out->resolved = SnapshotAnswers(SnapshotAnswers::allocator_type(returns_));
    std::vector<uint8_t> bytes;
    for (const traces::SnapshotVector* list : {lists.inputs, lists.outputs}) {
        if (!list) continue;
        for (const fbs::MemorySnapshot* s : *list) {
            RecentContents::Bytes kept = resolved_.find(s->hash());
            if (!kept) {
                {
                    std::lock_guard lock(reader_mutex_);
                    if (reader_.read_contents(s->hash(), &bytes)) continue;  // no answer
                }
                if (bytes.size() > kResolvedBytes / 4) continue;  // RecentContents keeps none
                kept = stage_bytes(bytes.data(), bytes.size());
                resolved_.keep(s->hash(), kept);
            }
            out->resolved_bytes += kept->size();
            out->resolved.emplace_back(s->hash(), std::move(kept));
        }
    }
}

bool RecordStage::publish(std::vector<StagedRecord>* batch, uint64_t bytes) {
    std::unique_lock lock(mutex_);
    while (!stopping_ && (ready_.size() >= kMaxReadyRecords || ready_bytes_ >= kMaxReadyBytes)) {
        stage_waiting_ = true;
        ready_changed_.wait(lock);
    }
    stage_waiting_ = false;
    if (stopping_) return false;
    for (StagedRecord& r : *batch) ready_.push_back(std::move(r));
    batch->clear();
    ready_bytes_ += bytes;
    if (consumer_waiting_.load(std::memory_order_relaxed)) ready_changed_.notify_all();
    return true;
}

void RecordStage::loop() {
    std::vector<StagedRecord> batch;
    batch.reserve(kBatchRecords);
    uint64_t bytes = 0;
    std::exception_ptr failure;
    try {
        for (;;) {
            StagedRecord r;
            if (!read(&r)) break;
            bytes += r.view.size;
            batch.push_back(std::move(r));
            // A replay thread that waits gets each record as soon as it is read.
            if (batch.size() >= kBatchRecords ||
                consumer_waiting_.load(std::memory_order_relaxed)) {
                if (!publish(&batch, bytes)) return;
                bytes = 0;
            }
        }
    } catch (...) {
        failure = std::current_exception();  // rethrown after the records read before it
    }
    if (!publish(&batch, bytes)) return;
    {
        std::lock_guard lock(mutex_);
        failure_ = failure;
        ended_ = true;
    }
    ready_changed_.notify_all();
}

bool RecordStage::next(StagedRecord* out) {
    if (next_taken_ == taken_.size()) {
        taken_.clear();  // moved from: nothing left to free
        next_taken_ = 0;
        std::unique_lock lock(mutex_);
        while (ready_.empty() && !ended_) {
            consumer_waiting_.store(true, std::memory_order_relaxed);
            ready_changed_.wait(lock);
        }
        consumer_waiting_.store(false, std::memory_order_relaxed);
        if (ready_.empty()) {
            if (failure_) std::rethrow_exception(failure_);
            return false;
        }
        taken_.swap(ready_);
        ready_bytes_ = 0;
        if (stage_waiting_) ready_changed_.notify_all();
    }
    *out = std::move(taken_[next_taken_++]);
    return true;
}

}  // namespace clastrace::replay::detail
