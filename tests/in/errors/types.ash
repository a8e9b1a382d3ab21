// Type and name errors in node bodies.
shader types(float a = 1.0, color c = 0.5, output float out, output color tint) {
    out = c;                        // color does not convert to float
    tint = vector(1, 0, 0);         // vector does not convert to color
    a = 2.0;                        // inputs are read-only
    out = missing + 1.0;            // unknown name
    out = c.x;                      // colors have .r/.g/.b
    out = dot(c, N);                // dot takes vectors
    break;                          // not in a loop
    out = pow(1.0);                 // wrong arity
    out = unknown_fn(1.0);          // unknown function
    string s = "a" + "b";           // no string arithmetic
}

float no_return(float x) {
    if (x > 0.0) { return x; }
}

float recursive(float x) { return recursive(x - 1.0); }
