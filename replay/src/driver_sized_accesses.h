// SPDX-License-Identifier: Apache-2.0
// A cluster command's accesses as the sync model takes them, at the sizes a driver may touch,
// and the engine record they view. Built at the command's turn (cluster_command.cpp), or by
// the command's run ahead on its worker (cluster_speculation.h), from the same record.
#pragma once

#include "cluster_size_queries.h"

#include <clastrace/engine/build_sizes.h>
#include <clastrace/engine/execution_record.h>
#include <clastrace/replay/sync_types.h>

#include <algorithm>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

namespace clastrace::replay::detail {

// The command's accesses for the sync model at the sizes a driver may touch: scratch spans the
// answered buildScratchSize; in implicit mode the answered region from dstImplicitData is
// written whole (the engine's packed objects keep their per-op fields, the bytes around them
// are named as the region, with its size and where the size comes from); in explicit mode each
// destination spans its explicit_destination_spans() entry.
struct DriverSizedAccesses {
    std::vector<Access> accesses;
    std::string scratch_field, region_field;  // what Access::field of those accesses views

    DriverSizedAccesses(const engine::ExecutionRecord& record, bool implicit,
                        const std::vector<uint64_t>& explicit_spans,
                        const ClusterDriverSizes& sizes) {
        scratch_field = "scratchData (the " + std::to_string(sizes.build_scratch_size) +
                        "-byte buildScratchSize " + sizes.source() + ")";
        region_field = "dstImplicitData (the " + std::to_string(sizes.acceleration_structure_size) +
                       "-byte implicit region " + sizes.source() + ")";
        std::vector<AddressRange> packed;
        // The unpacked region comes in at most one piece more than the objects packed in it.
        accesses.reserve(record.accesses.size() + (implicit ? record.ops.size() + 1 : 0));
        for (const engine::MemoryAccess& a : record.accesses) {
            if (a.end <= a.begin) continue;
            Access access{{a.begin, a.end}, a.stage, a.access, a.is_write, a.field};
            if (a.op_index < 0 && a.field == "scratchData") {
                access.range.end =
                    std::max(a.end, engine::sat_add(a.begin, sizes.build_scratch_size));
                access.field = scratch_field;
            } else if (implicit && a.is_write && a.field.starts_with("dstImplicitData[")) {
                packed.push_back(access.range);
            } else if (a.is_write && a.op_index >= 0 &&
                       size_t(a.op_index) < explicit_spans.size() &&
                       a.field.starts_with("*dstAddressesArray[")) {
                access.range.end =
                    std::max(a.end, engine::sat_add(a.begin, explicit_spans[size_t(a.op_index)]));
            }
            accesses.push_back(access);
        }
        if (implicit && !record.ops.empty()) add_unpacked_region(record, sizes, packed);
    }
    // A run ahead builds them on its worker and the command's turn moves them next to the
    // record (ClusterRunAhead::commit): the accesses that view the two texts above view the
    // moved ones.
    DriverSizedAccesses(DriverSizedAccesses&& other) noexcept
        : accesses(std::move(other.accesses)) {
        const char* scratch = other.scratch_field.data();
        const char* region = other.region_field.data();
        scratch_field = std::move(other.scratch_field);
        region_field = std::move(other.region_field);
        if (scratch_field.data() == scratch && region_field.data() == region) return;  // kept
        for (Access& a : accesses) {
            if (a.field.data() == scratch)
                a.field = scratch_field;
            else if (a.field.data() == region)
                a.field = region_field;
        }
    }
    DriverSizedAccesses& operator=(DriverSizedAccesses&&) = delete;

private:
    // The answered region less the engine's packed objects, as writes of the region.
    void add_unpacked_region(const engine::ExecutionRecord& record, const ClusterDriverSizes& sizes,
                             std::vector<AddressRange>& packed) {
        const uint64_t begin = record.implicit_address;
        const uint64_t end = engine::sat_add(begin, std::max(sizes.acceleration_structure_size,
                                                             record.implicit_bytes_used));
        std::sort(packed.begin(), packed.end(),
                  [](const AddressRange& a, const AddressRange& b) { return a.begin < b.begin; });
        uint64_t cursor = begin;
        auto unpacked = [&](uint64_t to) {
            if (cursor < to)
                accesses.push_back(Access{{cursor, to},
                                          engine::kStageBuild,
                                          engine::kAccessObjectWrite,
                                          true,
                                          region_field});
        };
        for (const AddressRange& r : packed) {
            unpacked(std::min(r.begin, end));
            cursor = std::max(cursor, r.end);
        }
        unpacked(end);
    }
};

// A command's engine record and the accesses made of it for the sync model, together: the
// model's feed keeps them until the model applied the call, so the accesses' field texts (views
// into the record's field names and DriverSizedAccesses' own strings) are not copied.
struct ModelAccesses {
    explicit ModelAccesses(engine::ExecutionRecord&& ran) : record(std::move(ran)) {}
    engine::ExecutionRecord record;
    std::optional<DriverSizedAccesses> sized;
};

}  // namespace clastrace::replay::detail
