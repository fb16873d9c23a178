"""The closest principled material to a reconstruction (issue 27): OpenPBR Surface parameters fitted to the BRDF
(:mod:`.fit`), their BRDF (:mod:`.model`, albedo tables in :mod:`.albedo`), and exporters for MaterialX
(:mod:`.materialx`), glTF 2.0 (:mod:`.gltf`) and Blender (:mod:`.blender`); :mod:`.outputs` wires them to
``gonio-reconstruct --principled / --materialx / --gltf / --blender``. docs/formats.md maps the parameters."""
