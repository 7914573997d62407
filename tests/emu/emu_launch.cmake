# cmake -DIN=backend_cuda.cu -DOUT=backend_cuda_emu.cc -P emu_launch.cmake
# Rewrites each CUDA launch `kernel<...><<<config>>>(` into `emu::launch("kernel<...>", kernel<...>,
# config)(` so that the host C++ compiler builds the file against tests/emu/cuda_runtime.h; no
# line is added or removed, and #line keeps diagnostics pointing at the original.
file(READ "${IN}" src)
string(REGEX REPLACE "([A-Za-z_][A-Za-z0-9_]*(<[^<>;]*>)?)<<<(([^;>]|->)*)>>>\\("
       "emu::launch(\"\\1\", \\1, \\3)(" out "${src}")
file(WRITE "${OUT}.tmp" "#line 1 \"${IN}\"\n${out}")
file(COPY_FILE "${OUT}.tmp" "${OUT}" ONLY_IF_DIFFERENT)
file(REMOVE "${OUT}.tmp")
