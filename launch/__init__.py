"""Launch files shipped with the package: `facesculpt launch demo` finds launch/demo.yaml."""
