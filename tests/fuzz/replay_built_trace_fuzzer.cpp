// SPDX-License-Identifier: Apache-2.0
// Fuzz target (docs/fuzzing.md): one cluster command whose every field and whose
// srcInfosArray bytes come from the fuzzer, written as a valid trace, replayed end to end
// (translation, engine, verification, sync model).
#include <clastrace/replay/replayer.h>
#include <clastrace/traces/trace_reader.h>
#include <clastrace/traces/trace_writer.h>
#include <clastrace/vk_cluster_abi.h>

#include <fuzzer/FuzzedDataProvider.h>

#include <cstdio>
#include <string>
#include <unistd.h>

using namespace clastrace;

namespace {

constexpr uint64_t kBase = 0x10000000, kBufferSize = 0x4000, kBuffers = 6;

template <class T>
fbs::RecordT record(T body) {
    fbs::RecordT r;
    r.body.Set(std::move(body));
    return r;
}

// kBuffers buffers of fuzzed usage, bound one after another to memory 1 at kBase.
void write_buffers(FuzzedDataProvider& in, traces::TraceWriter& writer) {
    for (uint64_t b = 0; b < kBuffers; ++b) {
        fbs::BufferCreateT c;
        c.buffer = 0x100 + b;
        c.size = kBufferSize;
        c.usage = in.ConsumeIntegral<uint32_t>();
        writer.append(record(c));
        fbs::BufferBindMemoryT bind;
        bind.buffer = c.buffer;
        bind.memory = 1;
        bind.memory_offset = b * kBufferSize;
        bind.device_address = kBase + b * kBufferSize;
        writer.append(record(bind));
    }
}

// Any address, or one inside the buffers.
uint64_t fuzzed_address(FuzzedDataProvider& in) {
    return in.ConsumeBool()
               ? in.ConsumeIntegral<uint64_t>()
               : kBase + in.ConsumeIntegralInRange<uint64_t>(0, kBuffers * kBufferSize);
}

// The op's input of one kind (triangle clusters, clusters' bottom level, moves) or none.
void set_op_input(FuzzedDataProvider& in, fbs::ClusterInputInfoT& input) {
    switch (in.ConsumeIntegralInRange(0, 3)) {
    case 0: {
        fbs::TriangleClusterInputT t;
        t.vertex_format = VK_FORMAT_R32G32B32_SFLOAT;
        t.max_cluster_triangle_count = in.ConsumeIntegralInRange<uint32_t>(0, 300);
        t.max_cluster_vertex_count = in.ConsumeIntegralInRange<uint32_t>(0, 300);
        t.max_total_triangle_count = in.ConsumeIntegral<uint32_t>();
        t.max_total_vertex_count = in.ConsumeIntegral<uint32_t>();
        t.max_cluster_unique_geometry_count = in.ConsumeIntegralInRange<uint32_t>(0, 4);
        input.op_input.Set(std::move(t));
        break;
    }
    case 1: {
        fbs::ClustersBottomLevelInputT t;
        t.max_total_cluster_count = in.ConsumeIntegralInRange<uint32_t>(0, 1000);
        t.max_cluster_count_per_acceleration_structure =
            in.ConsumeIntegralInRange<uint32_t>(0, 1000);
        input.op_input.Set(std::move(t));
        break;
    }
    case 2: {
        fbs::MoveObjectsInputT t;
        t.type = in.ConsumeIntegralInRange<uint32_t>(0, 3);
        t.no_move_overlap = in.ConsumeBool();
        t.max_moved_bytes = in.ConsumeIntegralInRange<uint64_t>(0, 1 << 20);
        input.op_input.Set(std::move(t));
        break;
    }
    default: break;
    }
}

// The command's address fields; the srcInfosArray's address is returned (inside a buffer).
uint64_t set_addresses(FuzzedDataProvider& in,
                       fbs::CmdBuildClusterAccelerationStructureIndirectT& b) {
    b.dst_implicit_data = fuzzed_address(in);
    b.scratch_data = fuzzed_address(in);
    b.dst_addresses_array =
        std::make_unique<fbs::StridedDeviceAddressRegion>(fuzzed_address(in),
                                                          in.ConsumeIntegralInRange(0, 64),
                                                          in.ConsumeIntegralInRange(0, 4096));
    b.dst_sizes_array =
        std::make_unique<fbs::StridedDeviceAddressRegion>(fuzzed_address(in),
                                                          in.ConsumeIntegralInRange(0, 64),
                                                          in.ConsumeIntegralInRange(0, 4096));
    const uint64_t infos = kBase + in.ConsumeIntegralInRange<uint64_t>(0, kBufferSize);
    b.src_infos_array =
        std::make_unique<fbs::StridedDeviceAddressRegion>(infos, in.ConsumeIntegralInRange(0, 128),
                                                          in.ConsumeIntegralInRange(0, 8192));
    b.src_infos_count = in.ConsumeBool() ? fuzzed_address(in) : 0;
    return infos;
}

// Fuzzed bytes as the srcInfosArray's input snapshot and, maybe, an output snapshot anywhere.
void add_snapshots(FuzzedDataProvider& in, traces::TraceWriter& writer, uint64_t infos,
                   fbs::CmdBuildClusterAccelerationStructureIndirectT& b) {
    std::vector<uint8_t> bytes =
        in.ConsumeBytes<uint8_t>(in.ConsumeIntegralInRange<size_t>(0, 2048));
    if (bytes.empty()) return;
    fbs::MemorySnapshot snap;
    if (!writer.snapshot(0, 0, infos, bytes.data(), bytes.size(), &snap)) b.inputs.push_back(snap);
    if (in.ConsumeBool() &&
        !writer.snapshot(0, 0, fuzzed_address(in), bytes.data(), bytes.size(), &snap))
        b.outputs.push_back(snap);
}

fbs::CmdBuildClusterAccelerationStructureIndirectT fuzzed_build(FuzzedDataProvider& in,
                                                                traces::TraceWriter& writer) {
    fbs::CmdBuildClusterAccelerationStructureIndirectT b;
    b.command_buffer = 0xc0;
    b.input = std::make_unique<fbs::ClusterInputInfoT>();
    b.input->max_acceleration_structure_count = in.ConsumeIntegralInRange<uint32_t>(0, 70);
    b.input->op_type = in.ConsumeIntegralInRange<uint32_t>(0, 6);
    b.input->op_mode = in.ConsumeIntegralInRange<uint32_t>(0, 3);
    set_op_input(in, *b.input);
    const uint64_t infos = set_addresses(in, b);
    b.address_resolution_flags = in.ConsumeBool() ? in.ConsumeIntegralInRange<uint32_t>(0, 63) : 0;
    add_snapshots(in, writer, infos, b);
    return b;
}

// Command buffer 0xc0 with one to three fuzzed builds, submitted once.
void write_command_buffer(FuzzedDataProvider& in, traces::TraceWriter& writer) {
    fbs::CommandBufferBeginT begin;
    begin.command_buffer = 0xc0;
    writer.append(record(begin));
    for (int command = 0, n = in.ConsumeIntegralInRange(1, 3); command < n; ++command)
        writer.append(record(fuzzed_build(in, writer)));
    fbs::CommandBufferEndT end;
    end.command_buffer = 0xc0;
    writer.append(record(end));
    fbs::QueueSubmitT submit;
    submit.queue = 1;
    auto batch = std::make_unique<fbs::SubmitBatchT>();
    batch->command_buffers.push_back(0xc0);
    submit.batches.push_back(std::move(batch));
    submit.submission_index = writer.next_submission_index();
    writer.append(record(std::move(submit)));
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    FuzzedDataProvider in(data, size);
    static const std::string path = "/tmp/replay_fuzz_" + std::to_string(getpid()) + ".clt";
    fbs::TraceHeaderT header;
    header.device = std::make_unique<fbs::DeviceInfoT>();
    header.device->driver_name = in.ConsumeBool() ? "clastrace engine" : "NVIDIA";
    traces::TraceError e;
    traces::TraceWriterOptions options;
    options.sync_on_finish = false;
    auto writer = traces::TraceWriter::create(path, header, options, &e);
    if (!writer) return 0;
    write_buffers(in, *writer);
    write_command_buffer(in, *writer);
    if (writer->finish()) return 0;
    writer.reset();
    auto reader = traces::TraceReader::open(path, &e);
    if (!reader) return 0;
    replay::ReplayOptions replay_options;
    replay_options.memory_budget_bytes = 1 << 20;
    replay::replay_trace(*reader, path, replay_options);
    return 0;
}
