"""UV bake, inpainting and image-to-UV projection (later issues)."""
