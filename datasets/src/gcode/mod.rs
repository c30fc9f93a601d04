//! G-code: a lexer and modal interpreter shared by every experiment (reader), and writers.
