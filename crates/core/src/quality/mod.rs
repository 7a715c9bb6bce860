//! Mesh-quality fixes of section 2.4, one file per fix.
