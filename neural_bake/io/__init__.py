"""Reading and writing: meshes (trimesh), images (OpenImageIO), atomic writes, colour spaces."""
