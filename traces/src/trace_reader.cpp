// SPDX-License-Identifier: Apache-2.0
#include "trace_reader_impl.h"

#include <algorithm>
#include <cstring>
#include <string>

namespace clastrace::traces {

using namespace reader;

uint64_t TraceReader::Impl::chunk_buffer_bytes() {
    if (ahead.valid()) ahead.wait();
    return raw.capacity() + ahead_raw.capacity() + older_raw[0].capacity() +
           older_raw[1].capacity() + side_raw.capacity() + ahead_decoding.side_raw.capacity() +
           decoder.compressed.capacity() + ahead_decoder.compressed.capacity();
}

TraceError TraceReader::Impl::open() {
    size = src->size();
    stats.file_size = size;
    raw_budget = options.max_raw_bytes ? options.max_raw_bytes : default_raw_budget(size);
    stats.raw_budget = raw_budget;
    if (size == 0) return error(TraceErrorCode::kTruncated, 0, "empty file");
    if (size < format::kFileHeaderSize) {
        if (size >= 8 && std::memcmp(read_small(0, 8).data(), format::kFileMagic, 8) != 0) {
            return error(TraceErrorCode::kNotATrace, 0, "not a clastrace trace (wrong magic)");
        }
        return error(TraceErrorCode::kTruncated, size,
                     "file of " + std::to_string(size) +
                         " bytes is shorter than the 32-byte file header");
    }
    format::FileHeader fh{};
    if (!src->read_at(0, sizeof fh, reinterpret_cast<uint8_t*>(&fh))) {
        return error(TraceErrorCode::kIoError, 0, "read failed: " + src->last_error());
    }
    if (std::memcmp(fh.magic, format::kFileMagic, 8) != 0) {
        return error(TraceErrorCode::kNotATrace, 0, "not a clastrace trace (wrong magic)");
    }
    version_major = fh.version_major;
    version_minor = fh.version_minor;
    if (fh.version_major != format::kVersionMajor) {
        return error(TraceErrorCode::kUnsupportedVersion,
                     offsetof(format::FileHeader, version_major),
                     "format version " + std::to_string(fh.version_major) + "." +
                         std::to_string(fh.version_minor) +
                         " is not supported (this reader reads " +
                         std::to_string(format::kVersionMajor) + ".x)");
    }
    if (fh.trace_header_size > format::kMaxTraceHeaderBytes ||
        fh.trace_header_size > size - format::kFileHeaderSize) {
        report(TraceErrorCode::kLengthOutOfRange, offsetof(format::FileHeader, trace_header_size),
               "trace header claims " + std::to_string(fh.trace_header_size) + " bytes (limit " +
                   std::to_string(format::kMaxTraceHeaderBytes) + ", file has " +
                   std::to_string(size - format::kFileHeaderSize) + " after the file header)");
        data_start = format::kFileHeaderSize;
        restart_at(data_start);
        resync(data_start);
    } else {
        header_bytes.resize(fh.trace_header_size);
        if (!src->read_at(format::kFileHeaderSize, header_bytes.size(), header_bytes.data())) {
            return error(TraceErrorCode::kIoError, format::kFileHeaderSize,
                         "read failed: " + src->last_error());
        }
        data_start = format::kFileHeaderSize + format::align8(fh.trace_header_size);
        // The padding to 8 bytes is outside every checksum, so it must be zero.
        uint64_t pad_at = format::kFileHeaderSize + fh.trace_header_size;
        if (data_start <= size) {
            std::vector<uint8_t> pad = read_small(pad_at, static_cast<size_t>(data_start - pad_at));
            if (std::any_of(pad.begin(), pad.end(), [](uint8_t b) { return b != 0; })) {
                report(TraceErrorCode::kBadChunk, pad_at,
                       "non-zero padding after the trace header");
            }
        }
        uint64_t computed =
            format::file_header_checksum(fh, header_bytes.data(), header_bytes.size());
        if (computed != fh.checksum) {
            report(TraceErrorCode::kChecksumMismatch, offsetof(format::FileHeader, checksum),
                   "file header checksum mismatch (stored " + hex(fh.checksum) + ", computed " +
                       hex(computed) + ")");
        } else {
            flatbuffers::Verifier verifier(header_bytes.data(), header_bytes.size(), 64, 1'000'000);
            if (!verifier.VerifyBuffer<fbs::TraceHeader>(nullptr)) {
                report(TraceErrorCode::kInvalidRecord, format::kFileHeaderSize,
                       "trace header fails the FlatBuffers verifier");
            } else {
                header = flatbuffers::GetRoot<fbs::TraceHeader>(header_bytes.data());
                if (header->capture()) {
                    unsigned bits = header->capture()->content_hash_bits();
                    if (bits >= 1 && bits <= 64) hash_bits = bits;
                }
            }
        }
        restart_at(data_start);
    }
    full_scan = true;
    open_index();
    return {};
}

std::vector<uint8_t> TraceReader::Impl::read_small(uint64_t at, size_t n) {
    std::vector<uint8_t> v(n);
    if (!src->read_at(at, n, v.data())) v.assign(n, 0);
    return v;
}

uint64_t default_raw_budget(uint64_t file_size) {
    const uint64_t relative = file_size > UINT64_MAX / kRawBudgetPerFileByte
                                  ? UINT64_MAX
                                  : file_size * kRawBudgetPerFileByte;
    return std::max(kRawBudgetFloorBytes, relative);
}

TraceReader::TraceReader(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
TraceReader::~TraceReader() = default;

std::unique_ptr<TraceReader> TraceReader::open_source(std::unique_ptr<ByteSource> src,
                                                      const std::string& name, TraceError* error,
                                                      const TraceReaderOptions& options) {
    auto impl = std::make_unique<Impl>();
    impl->options = options;
    impl->src = std::move(src);
    impl->name = name;
    if (TraceError e = impl->open()) {
        *error = std::move(e);
        return nullptr;
    }
    return std::unique_ptr<TraceReader>(new TraceReader(std::move(impl)));
}

std::unique_ptr<TraceReader> TraceReader::open(const std::string& path, TraceError* error,
                                               const TraceReaderOptions& options) {
    std::string why;
    auto src = open_file_source(path, &why);
    if (!src) {
        *error = make_trace_error(TraceErrorCode::kIoError, path, 0, "cannot open: " + why);
        return nullptr;
    }
    return open_source(std::move(src), path, error, options);
}

std::unique_ptr<TraceReader> TraceReader::open_memory(const uint8_t* data, size_t size,
                                                      const std::string& name, TraceError* error,
                                                      const TraceReaderOptions& options) {
    return open_source(memory_source(data, size), name, error, options);
}

uint16_t TraceReader::version_major() const { return impl_->version_major; }
uint16_t TraceReader::version_minor() const { return impl_->version_minor; }
uint16_t TraceReader::current_version_minor() { return format::kVersionMinor; }
bool TraceReader::timestamps_take_command_indices() const {
    return impl_->version_major == 1 && impl_->version_minor < 9;
}
const fbs::TraceHeader* TraceReader::header() const { return impl_->header; }
bool TraceReader::has_index() const { return impl_->index != nullptr; }
uint64_t TraceReader::indexed_submission_count() const {
    return impl_->index ? impl_->index->submission_count() : 0;
}
bool TraceReader::next(RecordView* out) { return impl_->next(out); }
TraceError TraceReader::seek_to_submission(uint64_t k) { return impl_->seek(k); }
TraceError TraceReader::read_contents(uint64_t hash, std::vector<uint8_t>* out) {
    return impl_->read_contents(hash, out);
}
TraceError TraceReader::read_contents_view(uint64_t hash, std::span<const uint8_t>* out) {
    return impl_->read_contents_view(hash, out);
}
const std::vector<TraceError>& TraceReader::damage() const { return impl_->damage; }
uint64_t TraceReader::damage_count() const { return impl_->damage_total; }
const TraceReadStats& TraceReader::stats() const {
    impl_->stats.raw_bytes_decompressed = impl_->raw_spent.load();
    impl_->stats.chunk_buffer_bytes = impl_->chunk_buffer_bytes();
    impl_->stats.real_bytes_allocated = impl_->pool->allocated_bytes();
    return impl_->stats;
}

}  // namespace clastrace::traces
