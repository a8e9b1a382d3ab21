// `for (;;)` is an endless loop that `break` leaves; without a `break` the loop budget ends it.
// Both bodies read `u`, so they run in the compiled code, not in the constant folder.
shader once(output float o) {
    o = 0.0;
    for (;;) {
        o = 0.75;
        if (u < 1000.0) break;
    }
}
shader forever(output float o) {
    o = 0.5;
    for (;;) {
      float a[65536];  o = u;
    }
}
substance a {
    node n = once();
    node m = mask(opacity: n.o);
    mask = m.out;
}
substance b {
    node n = forever();
    node m = mask(opacity: n.o);
    mask = m.out;
}
