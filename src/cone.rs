//! Normal cones: the smallest cone enclosing a set of unit normals, the cone of two cones, and the
//! back-facing tests that let a viewer cull a whole group at once.
