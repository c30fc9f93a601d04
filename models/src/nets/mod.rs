//! burn networks (flex backend).
