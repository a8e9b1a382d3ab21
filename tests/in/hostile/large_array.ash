// One array of the language's largest length: compiles to a fill loop (code size independent
// of the length) and fits the stack frame limit; JIT and interpreter agree. It reads `u`, so it
// is compiled rather than folded.
shader s(output float o) {
    float a[65536];
    for (int i = 0; i < 65536; i += 4097) {
        a[i] = float(i);
    }
    o = a[4097 * 3] / 65536.0 + a[1 + int(u * 0.5)];
}

substance a {
    node n = s();
    node d = displacement(height: n.o);
    displacement = d.out;
}
