// A diagnostic preload for suite runs (tools/catch-throw): every C++ exception thrown in the
// process is reported on stderr with its type and a backtrace before it is thrown on. A clean
// run throws none (checked on the whole suite: docs/decisions.md, "... a foreign exception
// hunted"), so any report names the library that threw; one that reaches a Vulkan call from
// Rust aborts the test with "Rust cannot catch foreign exceptions", and nextest keeps this
// report in its output.
// The interposition works for throws that reach __cxa_throw through the dynamic linker (the
// validation layer, LLVM, SPIRV-Tools and libstdc++'s own __throw_* helpers all call it so).
#define _GNU_SOURCE
#include <dlfcn.h>
#include <execinfo.h>
#include <fcntl.h>
#include <stdlib.h>
#include <stdio.h>
#include <unistd.h>

typedef void (*throw_fn)(void *, void *, void (*)(void *));

void __cxa_throw(void *obj, void *tinfo, void (*dest)(void *)) {
    static throw_fn real;
    if (!real) real = (throw_fn)dlsym(RTLD_NEXT, "__cxa_throw");
    // std::type_info is {vtable, const char *name}: the mangled name of the thrown type.
    const char *name = tinfo ? ((const char *const *)tinfo)[1] : "?";
    void *frames[64];
    int n = backtrace(frames, 64);
    // stderr (nextest keeps it with the test), and the file CATCH_THROW_LOG names if set (one
    // place to look after a whole suite).
    const char *log = getenv("CATCH_THROW_LOG");
    int fds[2] = {2, log ? open(log, O_WRONLY | O_CREAT | O_APPEND, 0644) : -1};
    for (int i = 0; i < 2; ++i) {
        if (fds[i] < 0) continue;
        dprintf(fds[i], "catch-throw: pid %d throws a C++ exception of type %s from:\n", (int)getpid(), name);
        backtrace_symbols_fd(frames, n, fds[i]);
    }
    if (fds[1] >= 0) close(fds[1]);
    real(obj, tinfo, dest);
    __builtin_unreachable();
}
