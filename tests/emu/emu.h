/* tests/emu/emu.h - what tests ask of the CPU imitation of the CUDA runtime (cuda_runtime.h in
 * this directory): its counters, fault injection and byte counting. C and C++. Tests only. */
#ifndef CLOTHD_EMU_H
#define CLOTHD_EMU_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef struct emu_counters {
    uint64_t kernel_launches;       /* kernels run, inside graphs or not */
    uint64_t graph_launches;        /* cudaGraphLaunch */
    uint64_t graph_instantiations;  /* cudaGraphInstantiate: a graph built */
    uint64_t graph_updates;         /* cudaGraphExecUpdate that succeeded: a graph changed in place */
    uint64_t captures;              /* cudaStreamEndCapture */
    uint64_t bytes_h2d, bytes_d2h, bytes_d2d; /* by cudaMemcpy(Async) */
    uint64_t copies_h2d, copies_d2h;          /* calls */
    uint64_t pageable_async_copies; /* cudaMemcpyAsync with pageable host memory (synchronous in fact) */
    uint64_t host_waits;            /* stream, event and device synchronizations */
    uint64_t device_bytes;          /* device memory allocated now */
    uint64_t device_bytes_peak;
    uint64_t pinned_bytes;          /* pinned host memory allocated now */
} emu_counters;

void emu_get_counters(emu_counters *out);
/* Zeroes the counters (device_bytes and pinned_bytes stay: they are what is allocated). */
void emu_reset_counters(void);

/* The k-th next cudaMalloc or cudaMallocHost from now fails with cudaErrorMemoryAllocation
 * (k = 0: the next one); k < 0 switches it off. */
void emu_fail_alloc_after(int k);
/* From now on every call that reaches the device fails with err (a cudaError_t value), as after a
 * lost device; 0 switches it off. */
void emu_fail_device(int err);

/* Counting of the distinct device-memory bytes each kernel launch reads and writes (through the
 * kernels' dload/dstore); slow, for the cost-model test. */
void emu_count_bytes(int on);
typedef struct emu_kernel_stats {
    char name[96];          /* the kernel as written at its launch, e.g. "k_cloth<MODE_VERLET, S, R>" */
    uint64_t launches;
    uint64_t threads;       /* threads launched, summed over launches */
    /* While counting (summed over the launches counted): */
    uint64_t read, written; /* distinct bytes of device memory read and written in each launch */
    uint64_t loads, stores; /* bytes of every load and store (a byte loaded twice counts twice) */
    uint64_t counted;       /* launches that were counted */
} emu_kernel_stats;
/* Copies up to cap entries, one per kernel, in order of first launch; returns how many there are. */
int emu_kernel_stats_get(emu_kernel_stats *out, int cap);
void emu_kernel_stats_reset(void);

#ifdef __cplusplus
}
#endif
#endif
