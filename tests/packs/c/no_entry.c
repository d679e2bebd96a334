/* A perfectly good shared library that is not a Kairos pack: it has no entry symbol. */
int not_a_pack(void) { return 42; }
