// A Kairos pack written in C++ against kairos.h: one component, `cpp.clamp`, that limits numbers to a
// range. Build it with the system compiler:
//
//     c++ -std=c++17 -O2 -shared -fPIC -I component-sdk/include component-packs/cpp-clamp/clamp.cpp \
//         -o packs/libkairos_pack_cpp.so
//
// Every function the runtime calls catches all exceptions: nothing may unwind into the runtime.

#include <algorithm>
#include <cstring>
#include <exception>
#include <new>
#include <string>

#include "kairos.h"

namespace {

kairos_str str(const char *text) { return kairos_str{reinterpret_cast<const uint8_t *>(text), std::strlen(text)}; }

void fail(kairos_error *error, const std::string &message) {
    if (error == nullptr || error->buffer == nullptr) return;
    const size_t len = std::min(message.size(), error->capacity);
    std::memcpy(error->buffer, message.data(), len);
    error->len = len;
}

double number_property(void *frame, const kairos_host *host, const char *name, double fallback) {
    kairos_value value{};
    if (host->property(frame, str(name), &value) != KAIROS_OK) return fallback;
    if (value.kind == 3) return value.number;
    if (value.kind == 2) return static_cast<double>(value.integer);
    return fallback;
}

struct Clamp {
    long long clamped = 0;
};

const char *const kDescriptor = R"json({
  "type_name": "cpp.clamp",
  "pack": "cpp",
  "label": "Clamp",
  "category": "math",
  "doc": "Limits each number to [min, max] (written in C++ against kairos.h)",
  "mode": "threaded",
  "inputs": [{"name": "in", "filter": {"one_of": ["f64", "i64"]}, "default_policy": "Fifo", "doc": "The signal"}],
  "outputs": [{"name": "out", "data_type": "f64", "default_buffer_size": 16, "doc": "The clamped signal, same timestamps"}],
  "properties": [
    {"name": "min", "kind": {"f64": {"min": null, "max": null}}, "default": -1.0, "live": true, "doc": "Lower limit"},
    {"name": "max", "kind": {"f64": {"min": null, "max": null}}, "default": 1.0, "live": true, "doc": "Upper limit"}
  ],
  "actions": []
})json";

void *create(const void *) {
    try {
        return new Clamp();
    } catch (...) {
        return nullptr;
    }
}

void destroy(void *instance) { delete static_cast<Clamp *>(instance); }

int32_t birth(void *, void *, const kairos_host *, kairos_error *) { return KAIROS_OK; }

int32_t core(void *instance, void *frame, const kairos_host *host, kairos_error *error) {
    try {
        auto *self = static_cast<Clamp *>(instance);
        kairos_sample in{};
        const int32_t status = host->read(frame, 0, 1, &in);
        if (status != KAIROS_OK) return status;
        double value = in.kind == KAIROS_I64 ? static_cast<double>(in.scalar_i64) : in.scalar_f64;
        const double low = number_property(frame, host, "min", -1.0);
        const double high = number_property(frame, host, "max", 1.0);
        const double limited = std::min(std::max(value, low), high);
        if (limited != value) ++self->clamped;
        kairos_sample out{};
        out.kind = KAIROS_F64;
        out.scalar_f64 = limited;
        out.timestamp_ns = in.timestamp_ns;
        return host->write(frame, 0, &out, 1, error);
    } catch (const std::exception &e) {
        fail(error, e.what());
        return KAIROS_FAILED;
    } catch (...) {
        fail(error, "unknown C++ exception");
        return KAIROS_FAILED;
    }
}

int32_t death(void *instance, void *frame, const kairos_host *host, kairos_error *) {
    auto *self = static_cast<Clamp *>(instance);
    const std::string message = "clamped " + std::to_string(self->clamped) + " samples";
    host->log(frame, 2, kairos_str{reinterpret_cast<const uint8_t *>(message.data()), message.size()});
    return KAIROS_OK;
}

int32_t property_changed(void *, void *, const kairos_host *, kairos_str, kairos_error *) { return KAIROS_OK; }

int32_t action(void *, void *, const kairos_host *, kairos_str, kairos_error *error) {
    fail(error, "cpp.clamp has no actions");
    return KAIROS_FAILED;
}

const kairos_component_vtable kComponents[] = {
    {str("cpp.clamp"), str(kDescriptor), nullptr, create, destroy, birth, core, death, property_changed, action},
};

const kairos_pack_descriptor kPack = {
    KAIROS_DESCRIPTOR_HEADER, str(KAIROS_SDK_VERSION), str("cpp"), str("0.1.0"), kComponents, 1,
};

}  // namespace

extern "C" const kairos_pack_descriptor *kairos_pack_entry(void) { return &kPack; }
