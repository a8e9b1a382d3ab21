// Eight 256 KiB local arrays: 2 MiB of stack frame. A diagnostic, not a crashed render thread.
shader s(output float o) {
    float a0[65536];
    float a1[65536];
    float a2[65536];
    float a3[65536];
    float a4[65536];
    float a5[65536];
    float a6[65536];
    float a7[65536];
    int i = int(u * 65535.0);
    o = a0[i] + a1[i] + a2[i] + a3[i] + a4[i] + a5[i] + a6[i] + a7[i];
}

substance a {
    node n = s();
    node m = mask(opacity: n.o);
    mask = m.out;
}
