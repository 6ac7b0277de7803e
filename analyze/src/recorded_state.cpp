// SPDX-License-Identifier: Apache-2.0
#include "command_events.h"

namespace clastrace::analyze::detail {

namespace {

// Every field of the input the answer depends on, so two queries compare as inputs.
std::vector<uint64_t> query_key(const fbs::ClusterInputInfo& in) {
    std::vector<uint64_t> k{in.op_type(), in.op_mode(), in.max_acceleration_structure_count(),
                            in.flags()};
    if (const auto* t = in.op_input_as_TriangleClusterInput()) {
        k.insert(k.end(), {t->vertex_format(), t->max_geometry_index_value(),
                           t->max_cluster_unique_geometry_count(), t->max_cluster_triangle_count(),
                           t->max_cluster_vertex_count(), t->max_total_triangle_count(),
                           t->max_total_vertex_count(), t->min_position_truncate_bit_count()});
    } else if (const auto* b = in.op_input_as_ClustersBottomLevelInput()) {
        k.insert(k.end(),
                 {b->max_total_cluster_count(), b->max_cluster_count_per_acceleration_structure()});
    } else if (const auto* m = in.op_input_as_MoveObjectsInput()) {
        k.insert(k.end(), {m->type(), uint64_t{m->no_move_overlap()}, m->max_moved_bytes()});
    }
    return k;
}

BuildSizesInfo answer_of(const fbs::GetClusterBuildSizes& q) {
    BuildSizesInfo s;
    const fbs::ClusterInputInfo& in = *q.input();
    s.max_acceleration_structure_count = in.max_acceleration_structure_count();
    if (const auto* t = in.op_input_as_TriangleClusterInput()) {
        s.max_total_triangles = t->max_total_triangle_count();
        s.max_total_vertices = t->max_total_vertex_count();
        s.max_cluster_triangles = t->max_cluster_triangle_count();
        s.max_cluster_vertices = t->max_cluster_vertex_count();
        s.min_position_truncate_bits = t->min_position_truncate_bit_count();
    }
    s.acceleration_structure_size = q.acceleration_structure_size();
    s.build_scratch_size = q.build_scratch_size();
    s.update_scratch_size = q.update_scratch_size();
    return s;
}

}  // namespace

void RecordedState::on_record(const fbs::Record& r) {
    switch (r.body_type()) {
    case fbs::RecordBody::BufferCreate: {
        const auto* c = r.body_as_BufferCreate();
        buffers_[c->buffer()] = BufferInfo{c->size(), 0};
        break;
    }
    case fbs::RecordBody::BufferBindMemory: {
        const auto* b = r.body_as_BufferBindMemory();
        auto it = buffers_.find(b->buffer());
        if (it == buffers_.end() || b->device_address() == 0 || it->second.size == 0) break;
        if (it->second.address) by_address_.erase(it->second.address);
        it->second.address = b->device_address();
        if (it->second.size <= UINT64_MAX - b->device_address())
            by_address_[b->device_address()] =
                Buffer{b->buffer(), b->device_address(), it->second.size};
        break;
    }
    case fbs::RecordBody::BufferDestroy: {
        auto it = buffers_.find(r.body_as_BufferDestroy()->buffer());
        if (it == buffers_.end()) break;
        auto placed = by_address_.find(it->second.address);
        if (placed != by_address_.end() && placed->second.handle == it->first)
            by_address_.erase(placed);
        buffers_.erase(it);
        break;
    }
    case fbs::RecordBody::AccelerationStructureCreate: {
        const auto* c = r.body_as_AccelerationStructureCreate();
        if (c->api() == 1)
            khr_objects_[c->acceleration_structure()] =
                KhrObject{c->buffer(), c->offset(), c->size(), c->type()};
        break;
    }
    case fbs::RecordBody::AccelerationStructureDestroy: {
        const uint64_t h = r.body_as_AccelerationStructureDestroy()->acceleration_structure();
        khr_objects_.erase(h);
        nv_object_bytes_.erase(h);
        nv_scratch_bytes_.erase(h);
        break;
    }
    case fbs::RecordBody::AccelerationStructureMemoryRequirementsNV: {
        const auto* q = r.body_as_AccelerationStructureMemoryRequirementsNV();
        if (q->type() == VK_ACCELERATION_STRUCTURE_MEMORY_REQUIREMENTS_TYPE_OBJECT_NV)
            nv_object_bytes_[q->acceleration_structure()] = q->size();
        else if (q->type() == VK_ACCELERATION_STRUCTURE_MEMORY_REQUIREMENTS_TYPE_BUILD_SCRATCH_NV)
            nv_scratch_bytes_[q->acceleration_structure()] = q->size();
        break;
    }
    case fbs::RecordBody::GetClusterBuildSizes: {
        const auto* q = r.body_as_GetClusterBuildSizes();
        if (!q->input()) break;
        const BuildSizesInfo answer = answer_of(*q);
        latest_query_[{q->input()->op_type(), q->input()->op_mode()}] = answer;
        std::vector<uint64_t> key = query_key(*q->input());
        auto it = queries_.find(key);
        if (it != queries_.end()) {
            it->second = answer;
        } else if (queries_.size() < kMaxQueries) {
            queries_.emplace(std::move(key), answer);
        } else {
            ++queries_dropped_;
        }
        break;
    }
    default: break;
    }
}

std::optional<RecordedState::Buffer> RecordedState::buffer_at(uint64_t address) const {
    auto it = by_address_.upper_bound(address);
    if (it == by_address_.begin()) return std::nullopt;
    --it;
    if (address - it->second.base >= it->second.size) return std::nullopt;
    return it->second;
}

std::optional<uint64_t> RecordedState::buffer_address(uint64_t handle) const {
    auto it = buffers_.find(handle);
    if (it == buffers_.end() || it->second.address == 0) return std::nullopt;
    return it->second.address;
}

std::optional<BuildSizesInfo> RecordedState::query_for(const fbs::ClusterInputInfo& input) const {
    auto it = queries_.find(query_key(input));
    if (it != queries_.end()) return it->second;
    auto latest = latest_query_.find({input.op_type(), input.op_mode()});
    if (latest != latest_query_.end()) return latest->second;
    return std::nullopt;
}

uint64_t RecordedState::nv_object_bytes(uint64_t handle) const {
    auto it = nv_object_bytes_.find(handle);
    return it == nv_object_bytes_.end() ? 0 : it->second;
}

uint64_t RecordedState::nv_build_scratch_bytes(uint64_t handle) const {
    auto it = nv_scratch_bytes_.find(handle);
    return it == nv_scratch_bytes_.end() ? 0 : it->second;
}

const RecordedState::KhrObject* RecordedState::khr_object(uint64_t handle) const {
    auto it = khr_objects_.find(handle);
    return it == khr_objects_.end() ? nullptr : &it->second;
}

}  // namespace clastrace::analyze::detail
