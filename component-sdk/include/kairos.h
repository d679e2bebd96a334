/*
 * kairos.h: the Kairos pack ABI for C and C++ packs.
 *
 * A pack is a shared library exporting one function, kairos_pack_entry(), that returns a pointer to a
 * static kairos_pack_descriptor. The runtime checks the magic number, the ABI version, the size of every
 * struct below (the layout check) and the SDK version before it calls anything else.
 *
 * Rules for pack authors:
 *  - Never let a C++ exception or a longjmp leave a function called by the runtime: catch everything and
 *    return KAIROS_FAILED with a message in the kairos_error buffer.
 *  - The host owns every sample. Bytes you read (kairos_sample.data) stay valid until your next read of the
 *    same input or until the call returns. Bytes you write are copied by the host during write().
 *  - An instance is used by one thread at a time but may move between threads.
 *  - Strings are UTF-8, passed as pointer + length (no terminator needed).
 *  - The library is never unloaded while the runtime runs.
 *
 * This header mirrors component-sdk/kairos-sdk-core/src/abi/types.rs and abi/mod.rs; a test compiles it and compares every size and constant.
 */
#ifndef KAIROS_H
#define KAIROS_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define KAIROS_ABI_MAGIC 0x4B4149524F53504BULL /* "KAIROSPK" */
#define KAIROS_ABI_VERSION 2u
#define KAIROS_SDK_VERSION "0.1.0"

/* Status codes returned by host and pack functions. */
#define KAIROS_OK 0
#define KAIROS_STOPPED 1       /* the component is being stopped: return it from core */
#define KAIROS_INTERRUPTED 2   /* a control request waits: return it from core */
#define KAIROS_END_OF_STREAM 3 /* the input's stream ended */
#define KAIROS_NO_DATA 4       /* nothing to read now */
#define KAIROS_FAILED 5        /* failed: the error buffer says why */

/* input_state() answers. */
#define KAIROS_INPUT_UNCONNECTED 0
#define KAIROS_INPUT_CONNECTED 1
#define KAIROS_INPUT_EXHAUSTED 2

/* Payload kinds (kairos_sample.kind) and the fields each uses. */
#define KAIROS_F64 1u         /* scalar_f64 */
#define KAIROS_I64 2u         /* scalar_i64 */
#define KAIROS_BOOL 3u        /* scalar_i64 != 0 */
#define KAIROS_VECTOR 4u      /* data: data_len / 8 native-endian doubles */
#define KAIROS_MATRIX 5u      /* height rows x width columns of doubles in data, row after row */
#define KAIROS_TEXT 6u        /* UTF-8 in data */
#define KAIROS_BYTES 7u       /* data */
#define KAIROS_IMAGE 8u       /* width, height, stride (bytes per row), pixel_format; pixels in data */
#define KAIROS_POINT_CLOUD 9u /* width points as x, y, z floats in data; if flags & 1, width intensities follow */
#define KAIROS_IMU 10u        /* values: gyro x y z (rad/s), accel x y z (m/s2); if flags & 1, quaternion x y z w */
#define KAIROS_GNSS_FIX 11u   /* values: lat, lon (deg), alt (m), h and v accuracy (m); scalar_i64: 0 none 1 fix 2 differential 3 RTK */
#define KAIROS_CAN_FRAME 12u  /* scalar_i64: identifier; flags & 1 extended, & 2 FD, & 4 remote request
                                 (no data; width: the length it asks for); data bytes in data */
#define KAIROS_POSE 13u       /* values: x y z (m), quaternion x y z w */
#define KAIROS_CUSTOM 14u     /* type_name and data */

/* Pixel formats (kairos_sample.pixel_format). */
#define KAIROS_GRAY8 1u
#define KAIROS_GRAY16 2u
#define KAIROS_RGB8 3u
#define KAIROS_RGBA8 4u
#define KAIROS_BGR8 5u
#define KAIROS_BGRA8 6u

typedef struct kairos_str {
    const uint8_t *ptr;
    size_t len;
} kairos_str;

typedef struct kairos_sample {
    uint32_t kind;
    uint32_t flags;
    int64_t timestamp_ns;     /* when the data originated, ns since the UNIX epoch */
    int64_t time_of_issue_ns; /* when it was last written */
    uint64_t sequence;
    double scalar_f64;
    int64_t scalar_i64;
    uint32_t width;
    uint32_t height;
    uint32_t stride;
    uint32_t pixel_format;
    double values[16];
    const uint8_t *data;
    size_t data_len;
    kairos_str type_name;
} kairos_sample;

/* A property value: kind 1 bool (integer 0/1), 2 integer, 3 number, 4 text. */
typedef struct kairos_value {
    uint32_t kind;
    int64_t integer;
    double number;
    kairos_str text; /* valid until the next property() call */
} kairos_value;

/* A host-owned buffer for an error message. */
typedef struct kairos_error {
    uint8_t *buffer;
    size_t capacity;
    size_t len;
} kairos_error;

/* The counters of the link feeding an input (input_counters()). written = read + skipped + overwritten +
 * queued holds exactly; latencies (time of issue - timestamp) are in nanoseconds. */
typedef struct kairos_link_counters {
    uint64_t written;
    uint64_t read;
    uint64_t skipped;
    uint64_t overwritten;
    uint64_t queued;
    uint64_t repeated; /* times a Sampling reader was given a sample again */
    uint64_t latency_count;
    int64_t latency_min_ns;
    int64_t latency_mean_ns;
    int64_t latency_p50_ns;
    int64_t latency_p99_ns;
    int64_t latency_max_ns;
} kairos_link_counters;

/* What the host offers a component. `frame` is the handle passed to the current call. */
typedef struct kairos_host {
    uint32_t struct_size;
    /* Blocks until input has a sample under its reader policy. */
    int32_t (*read)(void *frame, uint32_t input, int32_t interruptible, kairos_sample *out);
    /* Returns KAIROS_NO_DATA when nothing is there. */
    int32_t (*try_read)(void *frame, uint32_t input, kairos_sample *out);
    /* Sleeps until new data, a stop or a control request. */
    int32_t (*wait)(void *frame, int32_t interruptible);
    int32_t (*input_state)(void *frame, uint32_t input);
    /* keep_timestamp = 0: stamp timestamp and time of issue now; 1: keep sample->timestamp_ns. */
    int32_t (*write)(void *frame, uint32_t output, const kairos_sample *sample, int32_t keep_timestamp, kairos_error *error);
    int64_t (*now_ns)(void *frame);
    /* 1 when the deadline was reached, 0 when woken early (stop, pause, control request). */
    int32_t (*wait_until)(void *frame, int64_t deadline_ns);
    int32_t (*stop_requested)(void *frame);
    void (*set_period_ns)(void *frame, int64_t period_ns);
    int32_t (*property)(void *frame, kairos_str name, kairos_value *out);
    /* level: 0 error, 1 warning, 2 info, 3 debug. */
    void (*log)(void *frame, uint32_t level, kairos_str message);
    /* The instance as JSON, valid for the instance's life: {"id": "cam", "input_sources": ["a.out", null],
     * "clock": "real time ...", "diagram": "Diagram(...)"}. Unknown keys may be added; ignore them. */
    kairos_str (*instance_info)(void *frame);
    /* KAIROS_NO_DATA when the input is unconnected. */
    int32_t (*input_counters)(void *frame, uint32_t input, kairos_link_counters *out);
    /* Publishes the component's status, a JSON document the studio shows (a few times a second at most). */
    int32_t (*set_status)(void *frame, kairos_str json);
    /* Sleeps timeout_ns of real time or until woken: KAIROS_OK, KAIROS_STOPPED or KAIROS_INTERRUPTED. */
    int32_t (*sleep_ns)(void *frame, int64_t timeout_ns);
} kairos_host;

typedef int32_t (*kairos_lifecycle_fn)(void *instance, void *frame, const kairos_host *host, kairos_error *error);
typedef int32_t (*kairos_named_fn)(void *instance, void *frame, const kairos_host *host, kairos_str name, kairos_error *error);

/* One component type. descriptor_json is the component's descriptor as `kairos components --json` prints
 * one (type_name, category, doc, mode, inputs, outputs, properties, actions, and optionally label: the name
 * the studio shows); type_name must start with the pack's name and a dot. Every function must be given: a table with a NULL one is refused at load. */
typedef struct kairos_component_vtable {
    kairos_str type_name;
    kairos_str descriptor_json;
    const void *data;                   /* passed to create */
    void *(*create)(const void *data);  /* NULL: the constructor failed */
    void (*destroy)(void *instance);
    kairos_lifecycle_fn birth;
    kairos_lifecycle_fn core;
    kairos_lifecycle_fn death;
    kairos_named_fn property_changed;
    kairos_named_fn action;
} kairos_component_vtable;

typedef struct kairos_pack_descriptor {
    uint64_t magic;            /* KAIROS_ABI_MAGIC */
    uint32_t abi_version;      /* KAIROS_ABI_VERSION */
    uint32_t descriptor_size;  /* sizeof(kairos_pack_descriptor) */
    uint32_t sample_size;      /* sizeof(kairos_sample) */
    uint32_t host_size;        /* sizeof(kairos_host) */
    uint32_t vtable_size;      /* sizeof(kairos_component_vtable) */
    uint32_t value_size;       /* sizeof(kairos_value) */
    kairos_str sdk_version;    /* KAIROS_SDK_VERSION */
    kairos_str name;           /* the pack's name, as diagrams require it */
    kairos_str version;        /* the pack's semantic version */
    const kairos_component_vtable *components;
    size_t component_count;
} kairos_pack_descriptor;

/* The one symbol a pack exports. */
const kairos_pack_descriptor *kairos_pack_entry(void);

/* Fills the size fields and the magic/version of a descriptor. */
#define KAIROS_DESCRIPTOR_HEADER                                                                           \
    KAIROS_ABI_MAGIC, KAIROS_ABI_VERSION, (uint32_t)sizeof(kairos_pack_descriptor),                         \
        (uint32_t)sizeof(kairos_sample), (uint32_t)sizeof(kairos_host),                                    \
        (uint32_t)sizeof(kairos_component_vtable), (uint32_t)sizeof(kairos_value)

#ifdef __cplusplus
}
#endif

#endif /* KAIROS_H */
