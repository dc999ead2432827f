"""Launch files shipped with the package: `facesculpt launch demo` finds facesculpt/launch/demo.yaml."""
