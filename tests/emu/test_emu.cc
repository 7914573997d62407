/* test_emu.cc - the CPU imitation of the CUDA runtime against what CUDA documents: barriers and
 * their reductions, warp shuffles and ballots, dynamic shared memory, 0xff-filled allocations,
 * streams that run only when waited for, events between streams, capture and graph replay and
 * update, the errors CUDA gives for what a capture forbids, fault injection, byte counting, and a
 * kernel whose threads miss a barrier stopping the program. Plain C++ (no cmocka). */
#include "cuda_runtime.h"
#include "emu.h"

#include <sys/wait.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>

static int failures;
#define CHECK(cond)                                                                                    \
    do {                                                                                               \
        if (!(cond)) {                                                                                 \
            std::fprintf(stderr, "%s:%d: check failed: %s\n", __FILE__, __LINE__, #cond);              \
            failures++;                                                                                \
        }                                                                                              \
    } while (0)

/* out[b][t]: after a barrier, the value of thread (t + 1) mod n; then the block's or, and, count. */
__global__ void k_barrier(int *out, int *red)
{
    CS_DYNAMIC_SHARED(int, sh);
    const int t = (int)threadIdx.x, n = (int)blockDim.x, b = (int)blockIdx.x;
    sh[t] = t * 10 + b;
    __syncthreads();
    out[b * n + t] = sh[(t + 1) % n];
    const int o = __syncthreads_or(t == 7), a = __syncthreads_and(t < n), c = __syncthreads_count(t % 3 == 0);
    if (t == 0) {
        red[b * 3 + 0] = o;
        red[b * 3 + 1] = a;
        red[b * 3 + 2] = c;
    }
}

/* Shuffles and a ballot within each warp, and a tree sum as the backend writes it. */
__global__ void k_warp(float *down, int *idx, unsigned *ballot, float *sum)
{
    const int t = (int)threadIdx.x;
    const float v = (float)t;
    down[t] = __shfl_down_sync(0xffffffffu, v, 3);
    idx[t] = __shfl_sync(0xffffffffu, t, 5) + 1000 * __shfl_xor_sync(0xffffffffu, t, 1);
    const unsigned b = __ballot_sync(0xffffffffu, t % 2 == 0);
    if (t % 32 == 0) ballot[t / 32] = b;
    float s = v;
    for (int d = 16; d > 0; d >>= 1) s += __shfl_down_sync(0xffffffffu, s, (unsigned)d);
    if (t % 32 == 0) sum[t / 32] = s;
}

/* Half a warp shuffles under its own mask while the other half does not. */
__global__ void k_partial_mask(int *out)
{
    const int t = (int)threadIdx.x;
    if (t < 16) out[t] = __shfl_down_sync(0x0000ffffu, t, 1, 16);
    else out[t] = -t;
}

__global__ void k_copy(float *dst, const float *src, int n)
{
    const int i = (int)(blockIdx.x * blockDim.x + threadIdx.x);
    if (i < n) dstore(&dst[i], dload(&src[i]) + 1.0f);
}

/* Only half the block reaches the barrier: a bug the imitation must stop at. */
__global__ void k_divergent(int *out)
{
    if (threadIdx.x < 16) {
        __syncthreads();
        out[threadIdx.x] = 1;
    }
}

static void barriers()
{
    int *d_out, *d_red;
    const int blocks = 5, n = 96;
    CHECK(cudaMalloc((void **)&d_out, sizeof(int) * blocks * n) == cudaSuccess);
    CHECK(cudaMalloc((void **)&d_red, sizeof(int) * blocks * 3) == cudaSuccess);
    emu::launch("k_barrier", k_barrier, blocks, n, sizeof(int) * n)(d_out, d_red);
    CHECK(cudaGetLastError() == cudaSuccess);
    int out[blocks * n], red[blocks * 3];
    CHECK(cudaMemcpy(out, d_out, sizeof out, cudaMemcpyDeviceToHost) == cudaSuccess);
    CHECK(cudaMemcpy(red, d_red, sizeof red, cudaMemcpyDeviceToHost) == cudaSuccess);
    for (int b = 0; b < blocks; b++) {
        for (int t = 0; t < n; t++) CHECK(out[b * n + t] == ((t + 1) % n) * 10 + b);
        CHECK(red[b * 3 + 0] == 1);
        CHECK(red[b * 3 + 1] == 1);
        CHECK(red[b * 3 + 2] == 32); /* 0, 3, ..., 93 */
    }
    cudaFree(d_out);
    cudaFree(d_red);
}

static void warps()
{
    float *d_down, *d_sum;
    int *d_idx;
    unsigned *d_ballot;
    const int n = 64;
    cudaMalloc((void **)&d_down, sizeof(float) * n);
    cudaMalloc((void **)&d_idx, sizeof(int) * n);
    cudaMalloc((void **)&d_ballot, sizeof(unsigned) * 2);
    cudaMalloc((void **)&d_sum, sizeof(float) * 2);
    emu::launch("k_warp", k_warp, 1, n)(d_down, d_idx, d_ballot, d_sum);
    float down[n], sum[2];
    int idx[n];
    unsigned ballot[2];
    cudaMemcpy(down, d_down, sizeof down, cudaMemcpyDeviceToHost);
    cudaMemcpy(idx, d_idx, sizeof idx, cudaMemcpyDeviceToHost);
    cudaMemcpy(ballot, d_ballot, sizeof ballot, cudaMemcpyDeviceToHost);
    cudaMemcpy(sum, d_sum, sizeof sum, cudaMemcpyDeviceToHost);
    for (int t = 0; t < n; t++) {
        const int lane = t % 32;
        CHECK(down[t] == (float)(lane + 3 < 32 ? t + 3 : t)); /* lanes past the end keep their own */
        CHECK(idx[t] == (t / 32 * 32 + 5) + 1000 * (t ^ 1));
    }
    CHECK(ballot[0] == 0x55555555u && ballot[1] == 0x55555555u);
    CHECK(sum[0] == 496.0f && sum[1] == 496.0f + 32.0f * 32.0f); /* 0..31, 32..63 */

    int *d_pm, pm[32];
    cudaMalloc((void **)&d_pm, sizeof pm);
    emu::launch("k_partial_mask", k_partial_mask, 1, 32)(d_pm);
    cudaMemcpy(pm, d_pm, sizeof pm, cudaMemcpyDeviceToHost);
    for (int t = 0; t < 32; t++) CHECK(pm[t] == (t < 16 ? (t < 15 ? t + 1 : 15) : -t));
    cudaFree(d_down);
    cudaFree(d_idx);
    cudaFree(d_ballot);
    cudaFree(d_sum);
    cudaFree(d_pm);
}

/* Fresh memory reads as 0xff bytes (a NaN); a stream runs when waited for, not before. */
static void streams_and_memory()
{
    const int n = 1000;
    float *d_a, *d_b, *h;
    cudaStream_t s1, s2;
    cudaEvent_t e;
    CHECK(cudaMalloc((void **)&d_a, sizeof(float) * n) == cudaSuccess);
    CHECK(cudaMalloc((void **)&d_b, sizeof(float) * n) == cudaSuccess);
    CHECK(cudaMallocHost((void **)&h, sizeof(float) * n) == cudaSuccess);
    CHECK(cudaStreamCreateWithFlags(&s1, cudaStreamNonBlocking) == cudaSuccess);
    CHECK(cudaStreamCreateWithFlags(&s2, cudaStreamNonBlocking) == cudaSuccess);
    CHECK(cudaEventCreateWithFlags(&e, cudaEventDisableTiming) == cudaSuccess);
    CHECK(cudaMemcpyAsync(h, d_a, sizeof(float) * n, cudaMemcpyDeviceToHost, s1) == cudaSuccess);
    CHECK(cudaStreamSynchronize(s1) == cudaSuccess);
    CHECK(std::isnan(h[0]) && std::isnan(h[n - 1]));
    for (int i = 0; i < n; i++) h[i] = (float)i;
    CHECK(cudaMemcpyAsync(d_a, h, sizeof(float) * n, cudaMemcpyHostToDevice, s1) == cudaSuccess);
    emu::launch("k_copy", k_copy, (n + 127) / 128, 128, 0, s1)(d_b, d_a, n);
    CHECK(cudaEventRecord(e, s1) == cudaSuccess);
    CHECK(cudaStreamWaitEvent(s2, e, 0) == cudaSuccess);
    CHECK(cudaMemcpyAsync(h, d_b, sizeof(float) * n, cudaMemcpyDeviceToHost, s2) == cudaSuccess);
    CHECK(h[5] == 5.0f); /* nothing ran yet: the host sees what it wrote */
    CHECK(cudaStreamSynchronize(s2) == cudaSuccess); /* runs s1 up to the event first */
    CHECK(h[5] == 6.0f && h[n - 1] == (float)n);
    /* A copy to pageable memory completes before the call returns. */
    float pageable[4] = {0, 0, 0, 0};
    CHECK(cudaMemcpyAsync(pageable, d_b, sizeof pageable, cudaMemcpyDeviceToHost, s1) == cudaSuccess);
    CHECK(pageable[3] == 4.0f);
    /* Copies must stay inside allocations. */
    CHECK(cudaMemcpy(h, d_b + n - 2, sizeof(float) * 4, cudaMemcpyDeviceToHost) == cudaErrorInvalidValue);
    CHECK(cudaGetLastError() == cudaErrorInvalidValue);
    CHECK(cudaGetLastError() == cudaSuccess);

    /* Byte counting: k_copy reads and writes 4 bytes per element. */
    emu_kernel_stats_reset();
    emu_count_bytes(1);
    emu::launch("k_copy", k_copy, (n + 127) / 128, 128, 0, s1)(d_b, d_a, n);
    cudaStreamSynchronize(s1);
    emu_count_bytes(0);
    emu_kernel_stats ks[4];
    CHECK(emu_kernel_stats_get(ks, 4) == 1);
    CHECK(ks[0].launches == 1 && ks[0].counted == 1 && ks[0].read == 4u * n && ks[0].written == 4u * n);

    cudaEventDestroy(e);
    cudaStreamDestroy(s1);
    cudaStreamDestroy(s2);
    cudaFreeHost(h);
    cudaFree(d_a);
    cudaFree(d_b);
}

static void graphs()
{
    const int n = 256;
    float *d_a, *d_b, h[n];
    cudaStream_t s;
    cudaMalloc((void **)&d_a, sizeof(float) * n);
    cudaMalloc((void **)&d_b, sizeof(float) * n);
    cudaStreamCreateWithFlags(&s, cudaStreamNonBlocking);
    cudaMemsetAsync(d_a, 0, sizeof(float) * n, s);
    emu_counters c0, c1;
    emu_get_counters(&c0);
    cudaGraph_t g;
    CHECK(cudaStreamBeginCapture(s, cudaStreamCaptureModeThreadLocal) == cudaSuccess);
    emu::launch("k_copy", k_copy, 2, 128, 0, s)(d_b, d_a, n);
    emu::launch("k_copy", k_copy, 2, 128, 0, s)(d_a, d_b, n);
    CHECK(cudaStreamSynchronize(s) == cudaErrorStreamCaptureUnsupported); /* invalidates the capture */
    CHECK(cudaStreamEndCapture(s, &g) == cudaErrorStreamCaptureInvalidated && g == nullptr);
    cudaGetLastError();

    CHECK(cudaStreamBeginCapture(s, cudaStreamCaptureModeThreadLocal) == cudaSuccess);
    emu::launch("k_copy", k_copy, 2, 128, 0, s)(d_b, d_a, n);
    emu::launch("k_copy", k_copy, 2, 128, 0, s)(d_a, d_b, n);
    CHECK(cudaStreamEndCapture(s, &g) == cudaSuccess && g != nullptr);
    cudaGraphExec_t exec;
    CHECK(cudaGraphInstantiate(&exec, g, 0) == cudaSuccess);
    cudaGraphDestroy(g);
    for (int k = 0; k < 3; k++) CHECK(cudaGraphLaunch(exec, s) == cudaSuccess);
    cudaMemcpyAsync(h, d_a, sizeof h, cudaMemcpyDeviceToHost, s);
    CHECK(h[0] == 6.0f); /* three replays of +1 +1 */
    /* An update with the same kernels changes the parameters in place; another topology does not. */
    CHECK(cudaStreamBeginCapture(s, cudaStreamCaptureModeThreadLocal) == cudaSuccess);
    emu::launch("k_copy", k_copy, 2, 128, 0, s)(d_b, d_a, n / 2);
    emu::launch("k_copy", k_copy, 2, 128, 0, s)(d_a, d_b, n / 2);
    CHECK(cudaStreamEndCapture(s, &g) == cudaSuccess);
    cudaGraphExecUpdateResultInfo info;
    CHECK(cudaGraphExecUpdate(exec, g, &info) == cudaSuccess && info.result == cudaGraphExecUpdateSuccess);
    cudaGraphDestroy(g);
    CHECK(cudaGraphLaunch(exec, s) == cudaSuccess);
    cudaMemcpyAsync(h, d_a, sizeof h, cudaMemcpyDeviceToHost, s);
    CHECK(h[0] == 8.0f && h[n - 1] == 6.0f);
    CHECK(cudaStreamBeginCapture(s, cudaStreamCaptureModeThreadLocal) == cudaSuccess);
    emu::launch("k_copy", k_copy, 2, 128, 0, s)(d_b, d_a, n);
    CHECK(cudaStreamEndCapture(s, &g) == cudaSuccess);
    CHECK(cudaGraphExecUpdate(exec, g, &info) == cudaErrorGraphExecUpdateFailure &&
          info.result == cudaGraphExecUpdateErrorTopologyChanged);
    cudaGetLastError();
    cudaGraphDestroy(g);
    emu_get_counters(&c1);
    CHECK(c1.graph_instantiations - c0.graph_instantiations == 1);
    CHECK(c1.graph_updates - c0.graph_updates == 1);
    CHECK(c1.graph_launches - c0.graph_launches == 4);
    CHECK(c1.kernel_launches - c0.kernel_launches == 8);
    cudaGraphExecDestroy(exec);
    cudaStreamDestroy(s);
    cudaFree(d_a);
    cudaFree(d_b);
}

static void faults()
{
    void *p = nullptr, *q = nullptr;
    emu_fail_alloc_after(1);
    CHECK(cudaMalloc(&p, 16) == cudaSuccess);
    CHECK(cudaMalloc(&q, 16) == cudaErrorMemoryAllocation && q == nullptr);
    CHECK(cudaGetLastError() == cudaErrorMemoryAllocation);
    CHECK(cudaMalloc(&q, 16) == cudaSuccess);
    emu_fail_device(cudaErrorIllegalAddress);
    CHECK(cudaMemset(p, 0, 16) == cudaErrorIllegalAddress);
    emu_fail_device(0);
    cudaGetLastError();
    cudaFree(p);
    cudaFree(q);
}

/* Runs fn in a child process; true when it was stopped by abort() (SIGABRT). */
static bool aborts(void (*fn)())
{
    std::fflush(stdout);
    std::fflush(stderr);
    const pid_t pid = fork();
    if (pid == 0) {
        fn();
        cudaDeviceSynchronize();
        std::_Exit(0);
    }
    int status = 0;
    waitpid(pid, &status, 0);
    return WIFSIGNALED(status) && WTERMSIG(status) == SIGABRT;
}

static void divergent_barrier()
{
    int *d;
    cudaMalloc((void **)&d, sizeof(int) * 32);
    emu::launch("k_divergent", k_divergent, 1, 32)(d);
}

int main()
{
    barriers();
    warps();
    streams_and_memory();
    graphs();
    faults();
    std::printf("a kernel whose threads miss a barrier (its diagnosis follows):\n");
    CHECK(aborts(divergent_barrier));
    std::printf(failures ? "emulation: %d checks FAILED\n" : "emulation: every check passed\n", failures);
    return failures ? 1 : 0;
}
