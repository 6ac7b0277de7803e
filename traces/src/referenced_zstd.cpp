// SPDX-License-Identifier: Apache-2.0
#include <clastrace/traces/referenced_zstd.h>

#include <clastrace/traces/records.h>

#include <deque>
#include <unordered_map>
#include <vector>

#include <zstd.h>

namespace clastrace::traces {

namespace {

// Streams `bytes` (the end of the stream when `last`) into cctx, counting its output.
TraceError compress_more(ZSTD_CCtx* cctx, const std::vector<uint8_t>& bytes, bool last,
                         std::vector<uint8_t>& scratch, uint64_t* compressed) {
    ZSTD_inBuffer in{bytes.data(), bytes.size(), 0};
    for (;;) {
        ZSTD_outBuffer out{scratch.data(), scratch.size(), 0};
        const size_t left =
            ZSTD_compressStream2(cctx, &out, &in, last ? ZSTD_e_end : ZSTD_e_continue);
        if (ZSTD_isError(left)) {
            TraceError e;
            e.code = TraceErrorCode::kInvalidArgument;
            e.message = std::string("zstd failed: ") + ZSTD_getErrorName(left);
            return e;
        }
        *compressed += out.pos;
        if (last ? left == 0 : in.pos == in.size) return {};
    }
}

// The bytes of recent contents by key, so that one pass in file order compresses each snapshot
// as it comes (read_contents per snapshot would decompress chunks again and again).
class RecentContents {
public:
    static constexpr uint64_t kBudgetBytes = uint64_t{256} << 20;
    const std::vector<uint8_t>* find(uint64_t hash) const {
        auto it = by_hash_.find(hash);
        return it == by_hash_.end() ? nullptr : &it->second;
    }
    void keep(uint64_t hash, const uint8_t* data, size_t n) {
        if (n > kBudgetBytes || by_hash_.count(hash)) return;
        while (held_ + n > kBudgetBytes && !oldest_first_.empty()) {
            auto it = by_hash_.find(oldest_first_.front());
            held_ -= it->second.size();
            by_hash_.erase(it);
            oldest_first_.pop_front();
        }
        by_hash_.emplace(hash, std::vector<uint8_t>(data, data + n));
        oldest_first_.push_back(hash);
        held_ += n;
    }

private:
    std::unordered_map<uint64_t, std::vector<uint8_t>> by_hash_;
    std::deque<uint64_t> oldest_first_;
    uint64_t held_ = 0;
};

}  // namespace

TraceError referenced_zstd(const std::string& path, int zstd_level,
                           const TraceReaderOptions& options, ReferencedZstd* out) {
    *out = {};
    TraceError error;
    auto reader = TraceReader::open(path, &error, options);
    if (!reader) return error;
    if (zstd_level == 0) {
        const auto* h = reader->header();
        zstd_level =
            h && h->capture() && h->capture()->zstd_level() ? h->capture()->zstd_level() : 3;
    }
    out->zstd_level = zstd_level;
    ZSTD_CCtx* cctx = ZSTD_createCCtx();
    ZSTD_CCtx_setParameter(cctx, ZSTD_c_compressionLevel, zstd_level);
    std::vector<uint8_t> missed, scratch(ZSTD_CStreamOutSize());
    RecentContents recent;
    std::vector<uint64_t> hashes;
    RecordView view;
    while (!error && reader->next(&view)) {
        if (const std::optional<ContentsRecord> c = contents_record(*view.record)) {
            if (c->bytes) recent.keep(c->hash, c->data(), c->size());  // deltas come decoded
            continue;
        }
        hashes.clear();  // read_contents below ends the view: take the keys first
        const SnapshotLists lists = record_snapshots(*view.record);
        for (const SnapshotVector* list : {lists.inputs, lists.outputs})
            if (list)
                for (const fbs::MemorySnapshot* s : *list) {
                    ++out->snapshots;
                    out->referenced_bytes += s->size();
                    hashes.push_back(s->hash());
                }
        for (uint64_t hash : hashes) {
            const std::vector<uint8_t>* bytes = recent.find(hash);
            if (!bytes) {
                if ((error = reader->read_contents(hash, &missed))) break;
                bytes = &missed;
            }
            if ((error = compress_more(cctx, *bytes, false, scratch, &out->zstd_bytes))) break;
        }
    }
    if (!error) error = compress_more(cctx, {}, true, scratch, &out->zstd_bytes);
    ZSTD_freeCCtx(cctx);
    return error;
}

}  // namespace clastrace::traces
